//! Recorded EXR/HDR sequences as a frame source. (Being written.)
