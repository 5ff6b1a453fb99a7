//! Reading one HDR image file (`.exr` or `.hdr`) into linear RGB. (Being written.)
