//! Camera pixel formats: a raw V4L2 buffer → normalised code values (f32 RGB in [0, 1]).
//!
//! Nothing here touches a device, so every conversion is tested on made-up buffers. The output
//! is the camera's *code value* per channel, normalised by the format's largest code
//! (255, 1023, 4095, 16383 or 65535); turning code values into radiance is [`super::response`]'s job.
//!
//! | format             | V4L2 fourcc                 | conversion                                        |
//! |--------------------|-----------------------------|---------------------------------------------------|
//! | YUYV 4:2:2         | `YUYV`                      | limited-range Y'CbCr → R'G'B', BT.601 or BT.709   |
//! | packed 4:2:2       | `UYVY`, `YVYU`, `VYUY`      | the same, bytes U Y0 V Y1, Y0 V Y1 U, V Y0 U Y1   |
//! | packed 4:4:4       | `YUV3`, `AYUV`, `XYUV`, `VUYA`, `VUYX`, `YUVA`, `YUVX` | the same, a Cb Cr pair per pixel; alpha and padding bytes ignored |
//! | 10/12/16-bit Y'CbCr | `Y210`, `Y212`, `Y216` (as YUYV), `P010`, `P012` (as NV12) | the same on 16-bit words, the code in their high bits |
//! | Y'CbCr 4:2:0, planar | `NV12`, `NV21`, `YU12`, `YV12` | the same, one chroma pair per 2×2 pixels       |
//! | Y'CbCr 4:2:2, planar | `NV16`, `NV61`, `422P`, `YM61` | the same, one chroma pair per 2×1 pixels (as YUYV) |
//! | Y'CbCr 4:4:4, planar | `NV24`, `NV42`, `YM24`, `YM42` | the same, one chroma pair per pixel        |
//! | Motion JPEG        | `MJPG`, `JPEG`              | `zune-jpeg` (JFIF full-range BT.601) → RGB        |
//! | grey 8/10/12/14/16 | `GREY`, `Y10 `, `Y12 `, `Y14 `, `Y16 ` | one code per pixel (16-bit little-endian words), R = G = B |
//! | RGB24 / BGR24      | `RGB3`, `BGR3`              | byte order swapped for BGR                        |
//! | Bayer 8/10/12/14/16 | `RGGB` `BA81` …, `RG10` …, `RG12` …, `RG14` …, `RG16` `BYR2` … | bilinear demosaic |
//! | MIPI CSI-2 packed raw | `pRAA` `pBAA` `pGAA` `pgAA`, `pRCC` … `pgCC`, `pREE` … `pgEE`, `Y10P`, `Y12P`, `Y14P` | unpacked, then as Bayer or grey |
//!
//! MJPEG frames without Huffman tables (many UVC cameras leave them out, as Motion-JPEG in AVI
//! does) get an `AVI1` APP0 segment, which makes zune-jpeg use the standard tables of JPEG
//! Annex K.
//!
//! YUYV: each 4-byte group Y0 U Y1 V holds two pixels that share (U, V). With
//! y = (Y − 16)/219, u = (U − 128)/224, v = (V − 128)/224 (limited range),
//! R' = y + 2(1 − Kr)·v, B' = y + 2(1 − Kb)·u, G' = (y − Kr·R' − Kb·B')/(1 − Kr − Kb), with
//! (Kr, Kb) = (0.299, 0.114) for BT.601 and (0.2126, 0.0722) for BT.709 (ITU-R BT.601-7 and
//! BT.709-6). [`YuvMatrix::Auto`] picks BT.709 from 1280×720 up and BT.601 below (the usual HD/SD
//! convention); the V4L2 source first tries the colorspace the driver reports.
//!
//! 4:2:0 (single-planar V4L2: the planes follow each other in one buffer): `stride` is the luma
//! plane's bytes per row; its `height` rows are followed by the chroma. `NV12` (Cb, Cr) and
//! `NV21` (Cr, Cb) interleave the two chroma channels in one plane of height/2 rows of the same
//! stride; `YU12` (also called I420: Cb plane, then Cr) and `YV12` (Cr, then Cb) have two
//! planes of height/2 rows, each row stride/2 bytes. Each chroma pair is that of the 2×2 luma
//! pixels it covers (no interpolation, as YUYV's pair is its two pixels'). Width and height
//! must be even, and for the three-plane layouts the stride too. The 4:2:2 layouts are the
//! same with a chroma row for every luma row: `NV16` (Cb, Cr) and `NV61` (Cr, Cb) interleaved
//! in one plane of `height` rows, `422P` a Cb then a Cr plane of `height` rows of stride/2
//! bytes (`YM61`, a multi-planar node's YVU 4:2:2 in three planes, gathered into one buffer:
//! a Cr then a Cb plane); each chroma pair is that of the two pixels it covers, as in YUYV.
//! Their height may be odd. `P010` and `P012` are NV12 with a 16-bit little-endian word per
//! sample (the luma rows `stride` bytes apart, at least 2 × width), and `Y210`, `Y212`, `Y216`
//! YUYV with four words for two pixels; the code is in a word's high 10, 12 or 16 bits (the
//! bits below it are not read), and the limited range is scaled to the word (BT.2100's 10-bit
//! black 64 and white 940 are 4096 and 60160), so a word 256·c decodes to the bits of the byte
//! c. The packed 4:4:4 layouts hold a pixel in three bytes (`YUV3`: Y
//! Cb Cr) or four (`AYUV`/`XYUV`: alpha or padding, Y, Cb, Cr; `VUYA`/`VUYX`: Cr, Cb, Y,
//! alpha or padding; `YUVA`/`YUVX`: Y, Cb, Cr, alpha or padding), any width. The planar 4:4:4
//! layouts give every pixel its own pair: `NV24` (Cb, Cr)
//! and `NV42` (Cr, Cb) interleaved in one plane of `height` rows 2 × stride bytes apart, and
//! the multi-planar `YM24` (Cb plane, then Cr) and `YM42` (Cr, then Cb), gathered into one
//! buffer, planes of `height` rows of `stride` bytes; any width and height.
//!
//! Bayer demosaic (bilinear): each pixel keeps its own colour; a missing colour is the mean of
//! the pixels of that colour in its 3×3 neighbourhood (the 2 or 4 nearest samples). Borders are
//! mirrored without repeating the edge (x = −1 reads x = 1), which keeps the colour phase, so
//! every pixel has the same stencil. This reproduces a linear ramp exactly in every colour.
//! It runs in bands of rows: a band normalises its codes (and the rows above and below it) into
//! a small buffer of its own, and kernels specialised to the row's colours take the interior
//! pixels in pairs; only the two border columns use mirrored indices.
//!
//! 10/12/14/16-bit formats are the unpacked V4L2 layouts: one little-endian 16-bit word per
//! sample, the value in the low bits. Values above the format's largest code are clamped.
//! The MIPI CSI-2 packed layouts (what a Raspberry Pi's or another CSI-2 receiver's raw
//! capture gives) hold 10-bit samples four in five bytes (the high 8 bits of each, then a byte
//! of their low 2 bits, the first sample's in bits 0–1) and 12-bit samples two in three bytes
//! (the high 8 bits of each, then a byte of their low 4 bits, the first sample's in bits 0–3)
//! and 14-bit samples four in seven bytes (the high 8 bits of each, then their low 6 bits in
//! order from bit 0 of the fifth byte on: bits 0–5 the first sample's, 6–7 and 8–11 the
//! second's, and so on; Linux's `pixfmt-srggb14p`);
//! a row is width × 5/4, × 3/2 or × 7/4 bytes (the width a multiple of 4, 2 or 4), then
//! padding to the stride. They decode to the same codes, to the bit, as the unpacked layouts of the same
//! samples.
//!
//! Formats whose every code is one byte (MJPEG, RGB24, BGR24, 8-bit grey) can also be kept as
//! bytes ([`ByteImage`], [`decode_bytes_into_on`]): a quarter of the memory, linearised through
//! 256-entry tables to the same radiances as the code image gives (the camera source's path).
//! The other formats can be decoded a band of rows at a time ([`decode_each_band_on`]), so that
//! the linearisation takes each band's codes from the cache instead of a whole-frame image.
//!
//! Every buffer is checked before it is read: a short buffer, a stride smaller than a row, a
//! width the format does not allow (odd for packed 4:2:2, 4:2:0 and Bayer; not a multiple of 4
//! for the 10- and 14-bit CSI-2 packings), an odd height for 4:2:0, or a corrupt JPEG is a
//! [`PixelError`], never a panic.

use std::fmt;

/// Bayer colour-filter layout: the colours of the top-left 2×2 block, row by row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BayerPattern {
    Rggb,
    Bggr,
    Grbg,
    Gbrg,
}

impl BayerPattern {
    /// Channel index (0 = R, 1 = G, 2 = B) of the pixel at (x, y).
    #[inline]
    pub fn channel(self, x: usize, y: usize) -> usize {
        let cells: [usize; 4] = match self {
            BayerPattern::Rggb => [0, 1, 1, 2],
            BayerPattern::Bggr => [2, 1, 1, 0],
            BayerPattern::Grbg => [1, 0, 2, 1],
            BayerPattern::Gbrg => [1, 2, 0, 1],
        };
        cells[(y & 1) * 2 + (x & 1)]
    }
}

/// The layout of a planar Y'CbCr format, 4:2:0 or 4:2:2 (module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PlanarYuv {
    /// `NV12`: luma, then one plane of interleaved Cb, Cr (4:2:0).
    Nv12,
    /// `NV21`: luma, then one plane of interleaved Cr, Cb (4:2:0).
    Nv21,
    /// `YU12` (I420): luma, Cb plane, Cr plane (4:2:0).
    Yu12,
    /// `YV12`: luma, Cr plane, Cb plane (4:2:0).
    Yv12,
    /// `NV16`: luma, then one plane of interleaved Cb, Cr (4:2:2).
    Nv16,
    /// `NV61`: luma, then one plane of interleaved Cr, Cb (4:2:2).
    Nv61,
    /// `422P`: luma, Cb plane, Cr plane (4:2:2).
    Yuv422p,
    /// `NV24`: luma, then one plane of interleaved Cb, Cr, a pair for every pixel (4:4:4).
    Nv24,
    /// `NV42`: luma, then one plane of interleaved Cr, Cb (4:4:4).
    Nv42,
    /// `YM61` (YVU 4:2:2 in three planes on a multi-planar node, which has no one-buffer
    /// code): luma, Cr plane, Cb plane, gathered into one buffer.
    Yvu422p,
    /// `YM24` (YUV 4:4:4 in three planes, multi-planar only): luma, Cb plane, Cr plane.
    Yuv444p,
    /// `YM42` (YVU 4:4:4 in three planes, multi-planar only): luma, Cr plane, Cb plane.
    Yvu444p,
    /// `P010`: NV12's layout with a 16-bit little-endian word per sample, the 10-bit code in
    /// its high bits (4:2:0).
    P010,
    /// `P012`: the same with 12-bit codes.
    P012,
}

impl PlanarYuv {
    pub const ALL: [PlanarYuv; 14] = [
        PlanarYuv::Nv12,
        PlanarYuv::Nv21,
        PlanarYuv::Yu12,
        PlanarYuv::Yv12,
        PlanarYuv::Nv16,
        PlanarYuv::Nv61,
        PlanarYuv::Yuv422p,
        PlanarYuv::Nv24,
        PlanarYuv::Nv42,
        PlanarYuv::Yvu422p,
        PlanarYuv::Yuv444p,
        PlanarYuv::Yvu444p,
        PlanarYuv::P010,
        PlanarYuv::P012,
    ];

    /// The layout's fourcc, subsampling, planes, chroma order and bits per sample.
    fn geometry(self) -> PlanarGeometry {
        let g = |fourcc: &[u8; 4], rows_per, pixels_per, interleaved, cb_first| PlanarGeometry {
            fourcc: *fourcc,
            rows_per,
            pixels_per,
            interleaved,
            cb_first,
            bits: 8,
        };
        match self {
            PlanarYuv::Nv12 => g(b"NV12", 2, 2, true, true),
            PlanarYuv::Nv21 => g(b"NV21", 2, 2, true, false),
            PlanarYuv::Yu12 => g(b"YU12", 2, 2, false, true),
            PlanarYuv::Yv12 => g(b"YV12", 2, 2, false, false),
            PlanarYuv::Nv16 => g(b"NV16", 1, 2, true, true),
            PlanarYuv::Nv61 => g(b"NV61", 1, 2, true, false),
            PlanarYuv::Yuv422p => g(b"422P", 1, 2, false, true),
            PlanarYuv::Yvu422p => g(b"YM61", 1, 2, false, false),
            PlanarYuv::Nv24 => g(b"NV24", 1, 1, true, true),
            PlanarYuv::Nv42 => g(b"NV42", 1, 1, true, false),
            PlanarYuv::Yuv444p => g(b"YM24", 1, 1, false, true),
            PlanarYuv::Yvu444p => g(b"YM42", 1, 1, false, false),
            PlanarYuv::P010 => PlanarGeometry {
                bits: 10,
                ..g(b"P010", 2, 2, true, true)
            },
            PlanarYuv::P012 => PlanarGeometry {
                bits: 12,
                ..g(b"P012", 2, 2, true, true)
            },
        }
    }

    fn fourcc(self) -> [u8; 4] {
        self.geometry().fourcc
    }

    /// Luma rows per chroma row: 2 for 4:2:0, 1 for 4:2:2 and 4:4:4.
    pub fn rows_per_chroma_row(self) -> usize {
        self.geometry().rows_per
    }

    /// Pixels of a row per Cb, Cr pair: 2 for 4:2:0 and 4:2:2, 1 for 4:4:4.
    pub fn pixels_per_chroma_pair(self) -> usize {
        self.geometry().pixels_per
    }

    /// Whether Cb and Cr are interleaved in one plane (else each has a plane of its own, of
    /// the luma's row length for 4:4:4, half of it otherwise).
    pub fn interleaved(self) -> bool {
        self.geometry().interleaved
    }

    /// Significant bits per sample: 8, or 10 and 12 for `P010` and `P012`, whose samples are
    /// 16-bit words.
    pub fn bits(self) -> u8 {
        self.geometry().bits
    }

    /// Bytes per sample: 1, or 2 for the layouts of more than 8 bits.
    pub fn sample_bytes(self) -> usize {
        if self.bits() > 8 {
            2
        } else {
            1
        }
    }

    /// Where the chroma of a frame of this layout is, from the luma plane's `stride` and the
    /// frame's `height` (even for 4:2:0; for the three-plane layouts the stride too). An
    /// interleaved plane's rows are `stride` bytes apart, or twice that for 4:4:4 (a pair per
    /// pixel: V4L2's chroma bytes per line for `NV24`).
    fn chroma(self, stride: usize, height: usize) -> Option<ChromaPlanes> {
        let luma = stride.checked_mul(height)?;
        let rows = height / self.rows_per_chroma_row();
        let cb_first = self.geometry().cb_first;
        let sample = self.sample_bytes();
        let (first, second, stride, step) = if self.interleaved() {
            let chroma_stride = stride.checked_mul(2 / self.pixels_per_chroma_pair())?;
            (luma, luma + sample, chroma_stride, 2 * sample)
        } else {
            let chroma_stride = stride / self.pixels_per_chroma_pair();
            let second = luma.checked_add(chroma_stride.checked_mul(rows)?)?;
            (luma, second, chroma_stride, sample)
        };
        let (cb, cr) = if cb_first {
            (first, second)
        } else {
            (second, first)
        };
        Some(ChromaPlanes {
            cb,
            cr,
            stride,
            step,
            rows_per: self.rows_per_chroma_row(),
            pixels_per: self.pixels_per_chroma_pair(),
            sample_bytes: sample,
        })
    }
}

/// A planar layout's geometry ([`PlanarYuv::geometry`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct PlanarGeometry {
    fourcc: [u8; 4],
    /// Luma rows per chroma row.
    rows_per: usize,
    /// Pixels of a row per Cb, Cr pair.
    pixels_per: usize,
    /// Cb and Cr interleaved in one plane, or a plane each.
    interleaved: bool,
    /// Cb before Cr (in the plane, or as the first plane).
    cb_first: bool,
    /// Significant bits per sample (8: a byte; more: a 16-bit word, the code in its high bits).
    bits: u8,
}

/// Where a planar frame's chroma samples are in its buffer: the Cb and Cr of chroma pixel
/// (cx, cy) are at `cb` and `cr` + cy·`stride` + cx·`step`; chroma row cy covers the
/// `rows_per` luma rows from cy·`rows_per`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct ChromaPlanes {
    cb: usize,
    cr: usize,
    stride: usize,
    step: usize,
    rows_per: usize,
    /// Pixels of a row per pair: 2 (4:2:0, 4:2:2) or 1 (4:4:4).
    pixels_per: usize,
    /// Bytes per sample: 1, or 2 (a 16-bit little-endian word).
    sample_bytes: usize,
}

/// The layout of a packed Y'CbCr format: 4:2:2, two pixels in four bytes, or 4:4:4, one
/// pixel in three or four bytes (module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PackedYuv {
    /// `YUYV`: Y0 Cb Y1 Cr (4:2:2).
    Yuyv,
    /// `UYVY`: Cb Y0 Cr Y1 (4:2:2).
    Uyvy,
    /// `YVYU`: Y0 Cr Y1 Cb (4:2:2).
    Yvyu,
    /// `VYUY`: Cr Y0 Cb Y1 (4:2:2).
    Vyuy,
    /// `YUV3` (`V4L2_PIX_FMT_YUV24`): Y Cb Cr (4:4:4).
    Yuv24,
    /// `AYUV` (`V4L2_PIX_FMT_AYUV32`): alpha, Y, Cb, Cr (4:4:4).
    Ayuv32,
    /// `XYUV` (`V4L2_PIX_FMT_XYUV32`): padding, Y, Cb, Cr (4:4:4).
    Xyuv32,
    /// `VUYA` (`V4L2_PIX_FMT_VUYA32`): Cr, Cb, Y, alpha (4:4:4).
    Vuya32,
    /// `VUYX` (`V4L2_PIX_FMT_VUYX32`): Cr, Cb, Y, padding (4:4:4).
    Vuyx32,
    /// `YUVA` (`V4L2_PIX_FMT_YUVA32`): Y, Cb, Cr, alpha (4:4:4).
    Yuva32,
    /// `YUVX` (`V4L2_PIX_FMT_YUVX32`): Y, Cb, Cr, padding (4:4:4).
    Yuvx32,
    /// `Y210`: YUYV's order in 16-bit little-endian words, the 10-bit code in the high bits
    /// (4:2:2).
    Y210,
    /// `Y212`: the same with 12-bit codes.
    Y212,
    /// `Y216`: the same with 16-bit codes.
    Y216,
}

/// Where a packed Y'CbCr format's samples are in a group of `bytes` bytes that holds
/// `pixels` pixels (2 for 4:2:2, sharing one chroma pair; 1 for 4:4:4): the luma of pixel k is
/// sample `luma[k]`, the chroma samples `cb` and `cr`, each sample a byte, or a 16-bit
/// little-endian word for the layouts of more than 8 bits ([`PackedYuv::bits`]). Alpha and
/// padding bytes are not read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PackedYuvGroup {
    pub bytes: usize,
    pub pixels: usize,
    pub luma: [usize; 2],
    pub cb: usize,
    pub cr: usize,
}

impl PackedYuv {
    pub const ALL: [PackedYuv; 14] = [
        PackedYuv::Yuyv,
        PackedYuv::Uyvy,
        PackedYuv::Yvyu,
        PackedYuv::Vyuy,
        PackedYuv::Yuv24,
        PackedYuv::Ayuv32,
        PackedYuv::Xyuv32,
        PackedYuv::Vuya32,
        PackedYuv::Vuyx32,
        PackedYuv::Yuva32,
        PackedYuv::Yuvx32,
        PackedYuv::Y210,
        PackedYuv::Y212,
        PackedYuv::Y216,
    ];

    fn fourcc(self) -> [u8; 4] {
        match self {
            PackedYuv::Yuyv => *b"YUYV",
            PackedYuv::Uyvy => *b"UYVY",
            PackedYuv::Yvyu => *b"YVYU",
            PackedYuv::Vyuy => *b"VYUY",
            PackedYuv::Yuv24 => *b"YUV3",
            PackedYuv::Ayuv32 => *b"AYUV",
            PackedYuv::Xyuv32 => *b"XYUV",
            PackedYuv::Vuya32 => *b"VUYA",
            PackedYuv::Vuyx32 => *b"VUYX",
            PackedYuv::Yuva32 => *b"YUVA",
            PackedYuv::Yuvx32 => *b"YUVX",
            PackedYuv::Y210 => *b"Y210",
            PackedYuv::Y212 => *b"Y212",
            PackedYuv::Y216 => *b"Y216",
        }
    }

    /// Significant bits per sample: 8, or 10, 12 and 16 for `Y210`, `Y212` and `Y216`.
    pub fn bits(self) -> u8 {
        match self {
            PackedYuv::Y210 => 10,
            PackedYuv::Y212 => 12,
            PackedYuv::Y216 => 16,
            _ => 8,
        }
    }

    /// Where the samples are in a group (Linux's `pixfmt-packed-yuv`).
    pub fn group(self) -> PackedYuvGroup {
        let subsampled = |luma, cb, cr| PackedYuvGroup {
            bytes: 4,
            pixels: 2,
            luma,
            cb,
            cr,
        };
        let full = |bytes, y, cb, cr| PackedYuvGroup {
            bytes,
            pixels: 1,
            luma: [y, y],
            cb,
            cr,
        };
        match self {
            PackedYuv::Yuyv => subsampled([0, 2], 1, 3),
            PackedYuv::Uyvy => subsampled([1, 3], 0, 2),
            PackedYuv::Yvyu => subsampled([0, 2], 3, 1),
            PackedYuv::Vyuy => subsampled([1, 3], 2, 0),
            PackedYuv::Yuv24 => full(3, 0, 1, 2),
            PackedYuv::Ayuv32 | PackedYuv::Xyuv32 => full(4, 1, 2, 3),
            PackedYuv::Vuya32 | PackedYuv::Vuyx32 => full(4, 2, 1, 0),
            PackedYuv::Yuva32 | PackedYuv::Yuvx32 => full(4, 0, 1, 2),
            PackedYuv::Y210 | PackedYuv::Y212 | PackedYuv::Y216 => PackedYuvGroup {
                bytes: 8,
                ..subsampled([0, 2], 1, 3)
            },
        }
    }
}

/// The pixel formats envlight converts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PixelFormat {
    /// Packed Y'CbCr 4:2:2 (`YUYV`, `UYVY`, `YVYU`, `VYUY`; of 10 to 16 bits `Y210`, `Y212`,
    /// `Y216`) or 4:4:4 (`YUV3`, `AYUV`, `XYUV`, `VUYA`, `VUYX`, `YUVA`, `YUVX`).
    PackedYuv(PackedYuv),
    /// Planar Y'CbCr 4:2:0 (`NV12`, `NV21`, `YU12`, `YV12`; of 10 and 12 bits `P010`, `P012`),
    /// 4:2:2 (`NV16`, `NV61`, `422P`, `YM61`) or 4:4:4 (`NV24`, `NV42`, `YM24`, `YM42`).
    PlanarYuv(PlanarYuv),
    Mjpeg,
    /// Grey with 8, 10, 12, 14 or 16 significant bits.
    Grey {
        bits: u8,
    },
    Rgb24,
    Bgr24,
    /// Raw Bayer with 8, 10, 12, 14 or 16 significant bits.
    Bayer {
        pattern: BayerPattern,
        bits: u8,
    },
    /// MIPI CSI-2 packed raw, 10, 12 or 14 bits: Bayer, or grey where `pattern` is `None`.
    Csi2Packed {
        pattern: Option<BayerPattern>,
        bits: u8,
    },
}

/// The formats in envlight's default preference order (most dynamic range first).
pub const DEFAULT_PREFERENCE: [PixelFormat; 54] = {
    use BayerPattern::*;
    use PixelFormat::*;
    [
        Grey { bits: 16 },
        Bayer {
            pattern: Rggb,
            bits: 16,
        },
        Grey { bits: 14 },
        Bayer {
            pattern: Rggb,
            bits: 14,
        },
        Csi2Packed {
            pattern: None,
            bits: 14,
        },
        Csi2Packed {
            pattern: Some(Rggb),
            bits: 14,
        },
        Grey { bits: 12 },
        Bayer {
            pattern: Rggb,
            bits: 12,
        },
        Csi2Packed {
            pattern: None,
            bits: 12,
        },
        Csi2Packed {
            pattern: Some(Rggb),
            bits: 12,
        },
        Grey { bits: 10 },
        Bayer {
            pattern: Rggb,
            bits: 10,
        },
        Csi2Packed {
            pattern: None,
            bits: 10,
        },
        Csi2Packed {
            pattern: Some(Rggb),
            bits: 10,
        },
        Bayer {
            pattern: Bggr,
            bits: 16,
        },
        Bayer {
            pattern: Bggr,
            bits: 14,
        },
        Csi2Packed {
            pattern: Some(Bggr),
            bits: 14,
        },
        Bayer {
            pattern: Bggr,
            bits: 12,
        },
        Csi2Packed {
            pattern: Some(Bggr),
            bits: 12,
        },
        Bayer {
            pattern: Bggr,
            bits: 10,
        },
        Csi2Packed {
            pattern: Some(Bggr),
            bits: 10,
        },
        Bayer {
            pattern: Rggb,
            bits: 8,
        },
        PackedYuv(self::PackedYuv::Y216),
        PackedYuv(self::PackedYuv::Y212),
        PlanarYuv(self::PlanarYuv::P012),
        PackedYuv(self::PackedYuv::Y210),
        PlanarYuv(self::PlanarYuv::P010),
        Rgb24,
        Bgr24,
        PackedYuv(self::PackedYuv::Yuyv),
        PackedYuv(self::PackedYuv::Uyvy),
        PackedYuv(self::PackedYuv::Yvyu),
        PackedYuv(self::PackedYuv::Vyuy),
        PackedYuv(self::PackedYuv::Yuv24),
        PackedYuv(self::PackedYuv::Xyuv32),
        PackedYuv(self::PackedYuv::Ayuv32),
        PackedYuv(self::PackedYuv::Vuyx32),
        PackedYuv(self::PackedYuv::Vuya32),
        PackedYuv(self::PackedYuv::Yuvx32),
        PackedYuv(self::PackedYuv::Yuva32),
        PlanarYuv(self::PlanarYuv::Nv24),
        PlanarYuv(self::PlanarYuv::Yuv444p),
        PlanarYuv(self::PlanarYuv::Nv42),
        PlanarYuv(self::PlanarYuv::Yvu444p),
        PlanarYuv(self::PlanarYuv::Nv16),
        PlanarYuv(self::PlanarYuv::Yuv422p),
        PlanarYuv(self::PlanarYuv::Nv61),
        PlanarYuv(self::PlanarYuv::Yvu422p),
        PlanarYuv(self::PlanarYuv::Nv12),
        PlanarYuv(self::PlanarYuv::Yu12),
        PlanarYuv(self::PlanarYuv::Nv21),
        PlanarYuv(self::PlanarYuv::Yv12),
        Grey { bits: 8 },
        Mjpeg,
    ]
};

/// The MIPI CSI-2 packed layouts' fourccs (`V4L2_PIX_FMT_S….10P`, `….12P`, `….14P`, `Y10P`,
/// `Y12P`, `Y14P`).
const CSI2_FOURCCS: [(Option<BayerPattern>, u8, &[u8; 4]); 15] = {
    use BayerPattern::*;
    [
        (None, 10, b"Y10P"),
        (None, 12, b"Y12P"),
        (Some(Bggr), 10, b"pBAA"),
        (Some(Gbrg), 10, b"pGAA"),
        (Some(Grbg), 10, b"pgAA"),
        (Some(Rggb), 10, b"pRAA"),
        (Some(Bggr), 12, b"pBCC"),
        (Some(Gbrg), 12, b"pGCC"),
        (Some(Grbg), 12, b"pgCC"),
        (Some(Rggb), 12, b"pRCC"),
        (None, 14, b"Y14P"),
        (Some(Bggr), 14, b"pBEE"),
        (Some(Gbrg), 14, b"pGEE"),
        (Some(Grbg), 14, b"pgEE"),
        (Some(Rggb), 14, b"pREE"),
    ]
};

const BAYER_FOURCCS: [(BayerPattern, u8, &[u8; 4]); 20] = {
    use BayerPattern::*;
    [
        (Bggr, 8, b"BA81"),
        (Gbrg, 8, b"GBRG"),
        (Grbg, 8, b"GRBG"),
        (Rggb, 8, b"RGGB"),
        (Bggr, 10, b"BG10"),
        (Gbrg, 10, b"GB10"),
        (Grbg, 10, b"BA10"),
        (Rggb, 10, b"RG10"),
        (Bggr, 12, b"BG12"),
        (Gbrg, 12, b"GB12"),
        (Grbg, 12, b"BA12"),
        (Rggb, 12, b"RG12"),
        (Bggr, 14, b"BG14"),
        (Gbrg, 14, b"GB14"),
        (Grbg, 14, b"GR14"),
        (Rggb, 14, b"RG14"),
        (Bggr, 16, b"BYR2"),
        (Gbrg, 16, b"GB16"),
        (Grbg, 16, b"GR16"),
        (Rggb, 16, b"RG16"),
    ]
};

impl PixelFormat {
    /// Every format envlight converts (for tests and listings).
    pub fn all() -> Vec<PixelFormat> {
        let mut v = vec![
            PixelFormat::Mjpeg,
            PixelFormat::Grey { bits: 8 },
            PixelFormat::Grey { bits: 10 },
            PixelFormat::Grey { bits: 12 },
            PixelFormat::Grey { bits: 14 },
            PixelFormat::Grey { bits: 16 },
            PixelFormat::Rgb24,
            PixelFormat::Bgr24,
        ];
        v.extend(PackedYuv::ALL.map(PixelFormat::PackedYuv));
        v.extend(PlanarYuv::ALL.map(PixelFormat::PlanarYuv));
        v.extend(
            BAYER_FOURCCS
                .iter()
                .map(|&(pattern, bits, _)| PixelFormat::Bayer { pattern, bits }),
        );
        v.extend(
            CSI2_FOURCCS
                .iter()
                .map(|&(pattern, bits, _)| PixelFormat::Csi2Packed { pattern, bits }),
        );
        v
    }

    /// The V4L2 four-character code.
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::PackedYuv(layout) => layout.fourcc(),
            PixelFormat::PlanarYuv(layout) => layout.fourcc(),
            PixelFormat::Mjpeg => *b"MJPG",
            PixelFormat::Grey { bits: 10 } => *b"Y10 ",
            PixelFormat::Grey { bits: 12 } => *b"Y12 ",
            PixelFormat::Grey { bits: 14 } => *b"Y14 ",
            PixelFormat::Grey { bits: 16 } => *b"Y16 ",
            PixelFormat::Grey { .. } => *b"GREY",
            PixelFormat::Rgb24 => *b"RGB3",
            PixelFormat::Bgr24 => *b"BGR3",
            PixelFormat::Bayer { pattern, bits } => BAYER_FOURCCS
                .iter()
                .find(|&&(p, b, _)| p == pattern && b == bits)
                .map_or(*b"RGGB", |&(_, _, f)| *f),
            PixelFormat::Csi2Packed { pattern, bits } => CSI2_FOURCCS
                .iter()
                .find(|&&(p, b, _)| p == pattern && b == bits)
                .map_or(*b"pRAA", |&(_, _, f)| *f),
        }
    }

    /// The format of a V4L2 four-character code, `None` if envlight cannot convert it.
    pub fn from_fourcc(code: [u8; 4]) -> Option<Self> {
        Some(match &code {
            b"MJPG" | b"JPEG" => PixelFormat::Mjpeg,
            b"GREY" => PixelFormat::Grey { bits: 8 },
            b"Y10 " => PixelFormat::Grey { bits: 10 },
            b"Y12 " => PixelFormat::Grey { bits: 12 },
            b"Y14 " => PixelFormat::Grey { bits: 14 },
            b"Y16 " => PixelFormat::Grey { bits: 16 },
            b"RGB3" => PixelFormat::Rgb24,
            b"BGR3" => PixelFormat::Bgr24,
            _ => {
                if let Some(&layout) = PackedYuv::ALL.iter().find(|l| l.fourcc() == code) {
                    return Some(PixelFormat::PackedYuv(layout));
                }
                if let Some(&layout) = PlanarYuv::ALL.iter().find(|l| l.fourcc() == code) {
                    return Some(PixelFormat::PlanarYuv(layout));
                }
                if let Some(&(pattern, bits, _)) = CSI2_FOURCCS.iter().find(|(_, _, f)| **f == code)
                {
                    return Some(PixelFormat::Csi2Packed { pattern, bits });
                }
                let &(pattern, bits, _) = BAYER_FOURCCS.iter().find(|(_, _, f)| **f == code)?;
                PixelFormat::Bayer { pattern, bits }
            }
        })
    }

    /// Parses a config/CLI name: a fourcc (`"Y16"`, `"MJPG"`, `"RG10"`, `"NV12"`, `"pRAA"`;
    /// trailing spaces may be left out; matched exactly, else in upper case, since the CSI-2
    /// packed codes `pGAA` and `pgAA` differ in case only) or one of `yuyv`, `mjpeg`, `grey`,
    /// `rgb24`, `bgr24`, `i420` (`YU12`) (case-insensitive). A multi-planar node's
    /// separate-plane codes name the same formats as their one-buffer twins (`NM12` is
    /// `NV12`; [`super::v4l2_mplane::pixel_format`]).
    pub fn parse(name: &str) -> Option<Self> {
        let lower = name.trim().to_ascii_lowercase();
        match lower.as_str() {
            "yuyv" => return Some(PixelFormat::PackedYuv(PackedYuv::Yuyv)),
            "mjpeg" | "mjpg" => return Some(PixelFormat::Mjpeg),
            "grey" | "gray" => return Some(PixelFormat::Grey { bits: 8 }),
            "rgb24" => return Some(PixelFormat::Rgb24),
            "bgr24" => return Some(PixelFormat::Bgr24),
            "i420" => return Some(PixelFormat::PlanarYuv(PlanarYuv::Yu12)),
            _ => {}
        }
        let bytes = name.trim().as_bytes();
        if bytes.is_empty() || bytes.len() > 4 {
            return None;
        }
        let mut code = [b' '; 4];
        code[..bytes.len()].copy_from_slice(bytes);
        let read = super::v4l2_mplane::pixel_format;
        read(code).or_else(|| read(code.map(|b| b.to_ascii_uppercase())))
    }

    /// Significant bits per sample.
    pub fn bits(self) -> u8 {
        match self {
            PixelFormat::Grey { bits }
            | PixelFormat::Bayer { bits, .. }
            | PixelFormat::Csi2Packed { bits, .. } => bits,
            PixelFormat::PlanarYuv(layout) => layout.bits(),
            PixelFormat::PackedYuv(layout) => layout.bits(),
            _ => 8,
        }
    }

    /// Largest code value (2^bits − 1).
    pub fn code_max(self) -> f32 {
        ((1u32 << self.bits()) - 1) as f32
    }

    /// Bytes per pixel of a packed row (0 for the compressed MJPEG and for the CSI-2 packed
    /// layouts, whose pixels are not whole bytes: [`PixelFormat::row_bytes`]; for 4:2:0, of the
    /// luma plane's rows: [`PixelFormat::buffer_len`] gives a whole frame's).
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::PackedYuv(layout) => {
                let group = layout.group();
                group.bytes / group.pixels
            }
            PixelFormat::PlanarYuv(layout) => layout.sample_bytes(),
            PixelFormat::Mjpeg | PixelFormat::Csi2Packed { .. } => 0,
            PixelFormat::Rgb24 | PixelFormat::Bgr24 => 3,
            PixelFormat::Grey { bits } | PixelFormat::Bayer { bits, .. } => {
                if bits > 8 {
                    2
                } else {
                    1
                }
            }
        }
    }

    /// The bytes of one row of `width` pixels without padding (of the luma plane for 4:2:0; 0
    /// for MJPEG); for the CSI-2 packed layouts, width × 5/4 (10 bits), × 3/2 (12 bits) or
    /// × 7/4 (14 bits), rounded up (a width they do not allow is an error of [`check`]).
    pub fn row_bytes(self, width: u32) -> usize {
        let w = width as usize;
        match self {
            PixelFormat::Csi2Packed { bits: 10, .. } => w.div_ceil(4) * 5,
            PixelFormat::Csi2Packed { bits: 14, .. } => w.div_ceil(4) * 7,
            PixelFormat::Csi2Packed { .. } => w.div_ceil(2) * 3,
            other => w * other.bytes_per_pixel(),
        }
    }

    /// The bytes a `width`×`height` frame with rows `stride` bytes apart (0: packed) takes, the
    /// chroma planes of 4:2:0 included (the last row without its padding); `None` for MJPEG
    /// (any length) and for a size or stride the format does not allow
    /// ([`check`] says why).
    pub fn buffer_len(self, width: u32, height: u32, stride: usize) -> Option<usize> {
        match frame_layout(self, width, height, stride) {
            Ok((Layout::Packed { .. }, needed)) => Some(needed),
            _ => None,
        }
    }

    /// Whether code values are proportional to sensor exposure (raw grey and Bayer data) rather
    /// than gamma-encoded for display (Y'CbCr, MJPEG, RGB24 usually are).
    pub fn is_raw(self) -> bool {
        matches!(
            self,
            PixelFormat::Grey { .. } | PixelFormat::Bayer { .. } | PixelFormat::Csi2Packed { .. }
        )
    }

    /// Whether every code value of a frame is one byte as sent (MJPEG once decoded, RGB24,
    /// BGR24, 8-bit grey), so that [`decode_bytes_into_on`] can keep the frame as bytes and the
    /// linearisation can look each byte up in a 256-entry table
    /// ([`super::response::Linearizer::linearize_bytes_into_on`]). Y'CbCr and Bayer codes
    /// are computed from several bytes, so they are not.
    pub fn has_byte_codes(self) -> bool {
        matches!(
            self,
            PixelFormat::Mjpeg
                | PixelFormat::Rgb24
                | PixelFormat::Bgr24
                | PixelFormat::Grey { bits: 8 }
        )
    }
}

impl fmt::Display for PixelFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let code = self.fourcc();
        let s = String::from_utf8_lossy(&code);
        write!(f, "{}", s.trim_end())
    }
}

/// Y'CbCr → R'G'B' matrix of the packed and planar Y'CbCr formats.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum YuvMatrix {
    /// BT.709 from 1280×720 up, BT.601 below.
    #[default]
    Auto,
    Bt601,
    Bt709,
    /// ITU-R BT.2020's non-constant-luminance Y'CbCr (UHD and HDR video: HLG, PQ).
    Bt2020,
}

impl YuvMatrix {
    /// The matrix to use for a `width`×`height` frame (resolves `Auto`).
    pub fn resolve(self, width: u32, height: u32) -> YuvMatrix {
        match self {
            YuvMatrix::Auto if width >= 1280 && height >= 720 => YuvMatrix::Bt709,
            YuvMatrix::Auto => YuvMatrix::Bt601,
            m => m,
        }
    }

    fn coefficients(self) -> (f32, f32) {
        match self {
            YuvMatrix::Bt709 => (0.2126, 0.0722),
            YuvMatrix::Bt2020 => (0.2627, 0.0593),
            _ => (0.299, 0.114),
        }
    }
}

/// Why a buffer cannot be converted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PixelError {
    #[error("{format} {width}x{height}: buffer has {got} bytes, needs {needed}")]
    Short {
        format: PixelFormat,
        width: u32,
        height: u32,
        got: usize,
        needed: usize,
    },
    #[error("{format} {width}x{height}: {message}")]
    Geometry {
        format: PixelFormat,
        width: u32,
        height: u32,
        message: String,
    },
    #[error("MJPEG frame: {0}")]
    Jpeg(String),
}

/// One raw camera buffer and how to read it.
#[derive(Clone, Copy, Debug)]
pub struct RawFrame<'a> {
    pub data: &'a [u8],
    pub format: PixelFormat,
    pub width: u32,
    pub height: u32,
    /// Bytes per row; 0 = packed rows (width × bytes per pixel). Ignored for MJPEG.
    pub stride: usize,
}

/// An image of normalised code values in [0, 1], row-major, top row first.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CodeImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[f32; 3]>,
}

/// A frame of one-byte code values as the camera sent them (formats with
/// [`PixelFormat::has_byte_codes`]): MJPEG once decoded, RGB24, BGR24 (reordered to RGB) or
/// 8-bit grey. A quarter of the memory of a [`CodeImage`], and its linearisation is one
/// 256-entry table look-up per byte
/// ([`super::response::Linearizer::linearize_bytes_into_on`]), with the same radiances to the
/// bit as [`Self::to_codes_into_on`] followed by [`super::response::Linearizer::linearize_into_on`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ByteImage {
    pub width: u32,
    pub height: u32,
    /// Bytes per pixel: 3 (R, G, B) or 1 (grey, R = G = B).
    pub channels: usize,
    /// `channels` bytes per pixel, row-major, top row first.
    pub bytes: Vec<u8>,
}

impl ByteImage {
    /// The normalised code value of each byte, as [`decode_into_on`] computes it for the
    /// format the image came from: b / 255 for colour, b · (1/255) for grey.
    pub fn code_of_byte(&self) -> [f32; 256] {
        if self.channels == 1 {
            let inv = 1.0 / 255.0f32;
            std::array::from_fn(|b| f32::from(b as u8) * inv)
        } else {
            std::array::from_fn(|b| f32::from(b as u8) / 255.0)
        }
    }

    /// The normalised code values, as [`decode_into_on`] gives them for the same frame (to the
    /// bit); `out`'s allocation is reused.
    pub fn to_codes_into_on(&self, out: &mut CodeImage, pool: Option<&rayon::ThreadPool>) {
        let n = self.width as usize * self.height as usize;
        let codes = self.code_of_byte();
        out.width = self.width;
        out.height = self.height;
        // Every pixel is written below: a buffer of the right size is reused as it is.
        if out.pixels.len() != n {
            out.pixels.clear();
            out.pixels.resize(n, [0.0; 3]);
        }
        let (channels, w) = (self.channels.max(1), self.width as usize);
        each_row(pool, &mut out.pixels, w, |y, row| {
            let src = self
                .bytes
                .get(y * w * channels..(y + 1) * w * channels)
                .unwrap_or(&[]);
            // Pixels the image has no bytes for (it is shorter than its size says) are 0.
            if src.len() < w * channels {
                row.fill([0.0; 3]);
            }
            if channels == 1 {
                for (&b, d) in src.iter().zip(row.iter_mut()) {
                    *d = [codes[usize::from(b)]; 3];
                }
            } else {
                for (p, d) in src.chunks_exact(3).zip(row.iter_mut()) {
                    *d = [
                        codes[usize::from(p[0])],
                        codes[usize::from(p[1])],
                        codes[usize::from(p[2])],
                    ];
                }
            }
        });
    }
}

/// Keeps a frame of a one-byte-code format ([`PixelFormat::has_byte_codes`]) as bytes in
/// `out` (its allocation reused): a JPEG is decoded to RGB, BGR24 is reordered to RGB, RGB24
/// and 8-bit grey rows are copied without their padding. The buffer is checked as by
/// [`decode_into_on`], with the same errors; a format without one-byte codes is a
/// [`PixelError::Geometry`].
pub fn decode_bytes_into_on(
    raw: &RawFrame<'_>,
    out: &mut ByteImage,
    pool: Option<&rayon::ThreadPool>,
) -> Result<(), PixelError> {
    let (format, w, h) = (raw.format, raw.width, raw.height);
    if !format.has_byte_codes() {
        return Err(PixelError::Geometry {
            format,
            width: w,
            height: h,
            message: "codes are not one byte each".into(),
        });
    }
    let layout = check_layout(raw)?;
    out.width = w;
    out.height = h;
    let Layout::Packed {
        stride, row_bytes, ..
    } = layout
    else {
        out.channels = 3;
        return decode_jpeg_rgb8(raw.data, w, h, &mut out.bytes);
    };
    out.channels = format.bytes_per_pixel();
    if out.bytes.len() != row_bytes * h as usize {
        out.bytes.clear();
        out.bytes.resize(row_bytes * h as usize, 0);
    }
    let rows = |y: usize| &raw.data[y * stride..y * stride + row_bytes];
    each_row(pool, &mut out.bytes, row_bytes, |y, dst| {
        if format == PixelFormat::Bgr24 {
            for (px, d) in rows(y).chunks_exact(3).zip(dst.chunks_exact_mut(3)) {
                d.copy_from_slice(&[px[2], px[1], px[0]]);
            }
        } else {
            dst.copy_from_slice(rows(y));
        }
    });
    Ok(())
}

/// Largest frame accepted (pixels), so a corrupt size cannot allocate gigabytes.
pub const MAX_PIXELS: u64 = 16384 * 16384;

/// Converts a raw buffer into normalised code values. `matrix` is used for the Y'CbCr formats
/// only.
pub fn decode(raw: &RawFrame<'_>, matrix: YuvMatrix) -> Result<CodeImage, PixelError> {
    let mut out = CodeImage {
        width: 0,
        height: 0,
        pixels: Vec::new(),
    };
    decode_into(raw, matrix, &mut out)?;
    Ok(out)
}

/// [`decode`] into an existing image, reusing its allocation.
pub fn decode_into(
    raw: &RawFrame<'_>,
    matrix: YuvMatrix,
    out: &mut CodeImage,
) -> Result<(), PixelError> {
    decode_into_on(raw, matrix, out, None)
}

/// [`decode_into`] with bands of rows on the calling thread and `pool`'s helper threads
/// together (`None`: on the calling thread alone; src/parallel.rs).
/// Every pixel is converted by itself, so the result is the same to the bit either way.
pub fn decode_into_on(
    raw: &RawFrame<'_>,
    matrix: YuvMatrix,
    out: &mut CodeImage,
    pool: Option<&rayon::ThreadPool>,
) -> Result<(), PixelError> {
    let (w, h) = (raw.width, raw.height);
    let band_decoder = match check_layout(raw)? {
        Layout::Jpeg => return decode_jpeg(raw.data, w, h, out, pool),
        Layout::Packed {
            stride,
            row_bytes,
            chroma,
        } => BandDecoder::new(raw, matrix, (stride, row_bytes), chroma),
    };
    let n = w as usize * h as usize;
    out.width = w;
    out.height = h;
    // Every pixel is written below: a buffer of the right size is reused as it is.
    if out.pixels.len() != n {
        out.pixels.clear();
        out.pixels.resize(n, [0.0; 3]);
    }
    crate::parallel::for_each_chunk_mut(
        pool,
        &mut out.pixels,
        ROWS_PER_TASK * w as usize,
        |band, rows| band_decoder.decode(band * ROWS_PER_TASK, rows),
    );
    Ok(())
}

/// Decodes `raw` in bands of rows (32 each), each into a buffer of the band's size,
/// and calls `f(codes, out_rows)` with a band's codes and the same rows of `out` (resized to
/// width × height, every element left to `f`): a consumer of the codes (the linearisation,
/// [`super::response::Linearizer::decode_linearize_into_on`]) works on them while they are in
/// the cache, and no whole-frame code image is written or read. The bands run on the calling
/// thread and `pool`'s helpers together (src/parallel.rs); each band's codes are those of
/// [`decode_into_on`] to the bit. A JPEG is decoded whole first ([`decode_bytes_into_on`]).
pub fn decode_each_band_on<T: Copy + Default + Send>(
    raw: &RawFrame<'_>,
    matrix: YuvMatrix,
    out: &mut Vec<T>,
    pool: Option<&rayon::ThreadPool>,
    f: impl Fn(&[[f32; 3]], &mut [T]) + Sync,
) -> Result<(), PixelError> {
    let (w, h) = (raw.width as usize, raw.height as usize);
    let mut jpeg = ByteImage::default();
    let band_decoder = match check_layout(raw)? {
        Layout::Jpeg => {
            decode_bytes_into_on(raw, &mut jpeg, pool)?;
            None
        }
        Layout::Packed {
            stride,
            row_bytes,
            chroma,
        } => Some(BandDecoder::new(raw, matrix, (stride, row_bytes), chroma)),
    };
    if out.len() != w * h {
        out.clear();
        out.resize(w * h, T::default());
    }
    let codes_of_byte = jpeg.code_of_byte();
    crate::parallel::for_each_chunk_mut(pool, out, ROWS_PER_TASK * w, |band, out_rows| {
        let y0 = band * ROWS_PER_TASK;
        with_scratch(&BAND_CODES, out_rows.len(), |codes| {
            match &band_decoder {
                Some(decoder) => decoder.decode(y0, codes),
                None => {
                    let bytes = jpeg.bytes.get(3 * y0 * w..).unwrap_or(&[]);
                    for (d, p) in codes.iter_mut().zip(bytes.chunks_exact(3)) {
                        *d = std::array::from_fn(|c| codes_of_byte[usize::from(p[c])]);
                    }
                }
            }
            f(codes, out_rows);
        });
    });
    Ok(())
}

thread_local! {
    /// A band's codes in [`decode_each_band_on`], kept by each thread between bands and frames.
    static BAND_CODES: std::cell::RefCell<Vec<[f32; 3]>> = const { std::cell::RefCell::new(Vec::new()) };
    /// A band's mosaic rows in [`demosaic_band`], the same way.
    static BAND_MOSAIC: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Calls `f` with `len` elements of this thread's scratch buffer `buffer`, grown when needed
/// and never cleared: `f` must write every element before it reads it. Allocating and zeroing
/// a band's buffer every time cost as much as writing a whole-frame image (1280×960: 15 MB of
/// codes per frame). A nested use of the same buffer gets a new one.
fn with_scratch<T: Copy + Default, R>(
    buffer: &'static std::thread::LocalKey<std::cell::RefCell<Vec<T>>>,
    len: usize,
    f: impl FnOnce(&mut [T]) -> R,
) -> R {
    buffer.with(|cell| match cell.try_borrow_mut() {
        Ok(mut scratch) => {
            if scratch.len() < len {
                scratch.resize(len, T::default());
            }
            f(&mut scratch[..len])
        }
        Err(_) => f(&mut vec![T::default(); len]),
    })
}

/// A packed frame whose layout is checked, decoded a band of rows at a time.
struct BandDecoder<'a> {
    raw: &'a RawFrame<'a>,
    stride: usize,
    row_bytes: usize,
    /// A 4:2:0 frame's chroma planes.
    chroma: Option<ChromaPlanes>,
    /// The Y'CbCr formats' (Kr, Kb) for the frame's size.
    yuv: (f32, f32),
}

impl<'a> BandDecoder<'a> {
    fn new(
        raw: &'a RawFrame<'a>,
        matrix: YuvMatrix,
        (stride, row_bytes): (usize, usize),
        chroma: Option<ChromaPlanes>,
    ) -> Self {
        Self {
            raw,
            stride,
            row_bytes,
            chroma,
            yuv: matrix.resolve(raw.width, raw.height).coefficients(),
        }
    }

    /// Row `y`'s bytes.
    fn row(&self, y: usize) -> &[u8] {
        &self.raw.data[y * self.stride..y * self.stride + self.row_bytes]
    }

    /// The codes of rows `y0`, `y0 + 1`, … into `dst` (whole rows of the frame's width).
    fn decode(&self, y0: usize, dst: &mut [[f32; 3]]) {
        let format = self.raw.format;
        let (w, h) = (self.raw.width as usize, self.raw.height as usize);
        if w == 0 {
            return;
        }
        let rows = dst
            .chunks_exact_mut(w)
            .enumerate()
            .map(|(r, d)| (y0 + r, d));
        match format {
            PixelFormat::PackedYuv(layout) => {
                let to_rgb = YcbcrToRgb::new(self.yuv, format.bits());
                let group = layout.group();
                // A loop for each group size, known when it is compiled.
                let decode_row = match (group.bytes, group.pixels) {
                    _ if layout.bits() > 8 => packed_yuv16_row,
                    (4, 2) => packed_yuv_row::<4, 2>,
                    (3, 1) => packed_yuv_row::<3, 1>,
                    _ => packed_yuv_row::<4, 1>,
                };
                for (y, dst) in rows {
                    decode_row(self.row(y), dst, group, &to_rgb);
                }
            }
            PixelFormat::PlanarYuv(_) => {
                let to_rgb = YcbcrToRgb::new(self.yuv, format.bits());
                let Some(chroma) = self.chroma else { return };
                let data = self.raw.data;
                // Checked by `check_layout`: every chroma sample of the frame is in `data`.
                let chroma_row = |start: usize, y: usize, len: usize| {
                    let from = start + (y / chroma.rows_per) * chroma.stride;
                    &data[from..from + len]
                };
                for (y, dst) in rows {
                    let luma = self.row(y).chunks_exact(2);
                    let pairs = dst.chunks_exact_mut(2);
                    if chroma.sample_bytes == 2 {
                        // 16-bit words (P010, P012): one interleaved plane of pairs.
                        let mask = to_rgb.word_mask;
                        let words = |b: &[u8]| u16::from_le_bytes([b[0], b[1]]) & mask;
                        let (first, cb_first) = (chroma.cb.min(chroma.cr), chroma.cb < chroma.cr);
                        let cbcr = chroma_row(first, y, 2 * w).chunks_exact(4);
                        for ((l, c), pair) in self.row(y).chunks_exact(4).zip(cbcr).zip(pairs) {
                            let (a, b) = (words(&c[..2]), words(&c[2..]));
                            let (u, v) = if cb_first { (a, b) } else { (b, a) };
                            pair[0] = to_rgb.pixel16(words(&l[..2]), u, v);
                            pair[1] = to_rgb.pixel16(words(&l[2..]), u, v);
                        }
                    } else if chroma.step == 2 && chroma.pixels_per == 1 {
                        // 4:4:4: a Cb, Cr pair (Cr, Cb for NV42) for every pixel.
                        let cb_first = chroma.cb < chroma.cr;
                        let cbcr = chroma_row(chroma.cb.min(chroma.cr), y, 2 * w).chunks_exact(2);
                        for ((&l, c), px) in self.row(y).iter().zip(cbcr).zip(dst.iter_mut()) {
                            let (u, v) = if cb_first { (c[0], c[1]) } else { (c[1], c[0]) };
                            *px = to_rgb.pixel(l, u, v);
                        }
                    } else if chroma.step == 2 {
                        // One plane of interleaved pairs: Cb first (NV12) or Cr first (NV21).
                        let cb_first = chroma.cb < chroma.cr;
                        let cbcr = chroma_row(chroma.cb.min(chroma.cr), y, w).chunks_exact(2);
                        for ((l, c), pair) in luma.zip(cbcr).zip(pairs) {
                            let (u, v) = if cb_first { (c[0], c[1]) } else { (c[1], c[0]) };
                            to_rgb.pair([l[0], l[1]], u, v, pair);
                        }
                    } else if chroma.pixels_per == 1 {
                        // 4:4:4 in three planes: a Cb and a Cr sample for every pixel.
                        let (cb, cr) = (chroma_row(chroma.cb, y, w), chroma_row(chroma.cr, y, w));
                        let samples = self.row(y).iter().zip(cb).zip(cr);
                        for (((&l, &u), &v), px) in samples.zip(dst.iter_mut()) {
                            *px = to_rgb.pixel(l, u, v);
                        }
                    } else {
                        let (cb, cr) = (
                            chroma_row(chroma.cb, y, w / 2),
                            chroma_row(chroma.cr, y, w / 2),
                        );
                        for (((l, &u), &v), pair) in luma.zip(cb).zip(cr).zip(pairs) {
                            to_rgb.pair([l[0], l[1]], u, v, pair);
                        }
                    }
                }
            }
            PixelFormat::Rgb24 | PixelFormat::Bgr24 => {
                let (ri, bi) = if format == PixelFormat::Rgb24 {
                    (0, 2)
                } else {
                    (2, 0)
                };
                for (y, dst) in rows {
                    for (px, d) in self.row(y).chunks_exact(3).zip(dst.iter_mut()) {
                        *d = [
                            f32::from(px[ri]) / 255.0,
                            f32::from(px[1]) / 255.0,
                            f32::from(px[bi]) / 255.0,
                        ];
                    }
                }
            }
            PixelFormat::Grey { .. } => {
                let max = format.code_max();
                let inv = 1.0 / max;
                for (y, dst) in rows {
                    if format.bytes_per_pixel() == 1 {
                        for (&b, d) in self.row(y).iter().zip(dst.iter_mut()) {
                            *d = [f32::from(b) * inv; 3];
                        }
                    } else {
                        for (b, d) in self.row(y).chunks_exact(2).zip(dst.iter_mut()) {
                            let v = f32::from(u16::from_le_bytes([b[0], b[1]])).min(max) * inv;
                            *d = [v; 3];
                        }
                    }
                }
            }
            PixelFormat::Bayer { pattern, .. } => {
                let max = format.code_max();
                let inv = 1.0 / max;
                // The band reads its codes (and one row above and below) into a small buffer
                // of its own and demosaics from there: no whole-frame mosaic.
                let read_row = |y: usize, dst: &mut [f32]| {
                    if format.bytes_per_pixel() == 1 {
                        for (&b, d) in self.row(y).iter().zip(dst.iter_mut()) {
                            *d = f32::from(b) * inv;
                        }
                    } else {
                        for (b, d) in self.row(y).chunks_exact(2).zip(dst.iter_mut()) {
                            *d = f32::from(u16::from_le_bytes([b[0], b[1]])).min(max) * inv;
                        }
                    }
                };
                demosaic_band(w, h, pattern, read_row, y0, dst);
            }
            PixelFormat::Csi2Packed { pattern, bits } => {
                let inv = 1.0 / format.code_max();
                let read_row =
                    |y: usize, dst: &mut [f32]| unpack_csi2_row(bits, self.row(y), inv, dst);
                match pattern {
                    Some(pattern) => demosaic_band(w, h, pattern, read_row, y0, dst),
                    None => with_scratch(&BAND_MOSAIC, w, |row| {
                        for (y, dst) in rows {
                            read_row(y, row);
                            for (&v, d) in row.iter().zip(dst.iter_mut()) {
                                *d = [v; 3];
                            }
                        }
                    }),
                }
            }
            // Not a packed format: its layout is `Layout::Jpeg`.
            PixelFormat::Mjpeg => {}
        }
    }
}

/// One row of MIPI CSI-2 packed `bits`-bit samples (module doc) as normalised codes
/// (code × `inv`) into `out` (as many as the row holds).
#[inline]
fn unpack_csi2_row(bits: u8, row: &[u8], inv: f32, out: &mut [f32]) {
    if bits == 10 {
        for (group, d) in row.chunks_exact(5).zip(out.chunks_exact_mut(4)) {
            let low = group[4];
            for k in 0..4 {
                let code = (u16::from(group[k]) << 2) | u16::from((low >> (2 * k)) & 0b11);
                d[k] = f32::from(code) * inv;
            }
        }
    } else if bits == 14 {
        for (group, d) in row.chunks_exact(7).zip(out.chunks_exact_mut(4)) {
            // The four 6-bit low parts, in order from bit 0 of byte 4.
            let low = u32::from(group[4]) | u32::from(group[5]) << 8 | u32::from(group[6]) << 16;
            for k in 0..4 {
                let code = (u32::from(group[k]) << 6) | ((low >> (6 * k)) & 0x3F);
                d[k] = code as f32 * inv;
            }
        }
    } else {
        for (group, d) in row.chunks_exact(3).zip(out.chunks_exact_mut(2)) {
            let low = group[2];
            d[0] = f32::from((u16::from(group[0]) << 4) | u16::from(low & 0xF)) * inv;
            d[1] = f32::from((u16::from(group[1]) << 4) | u16::from(low >> 4)) * inv;
        }
    }
}

/// A row of a packed Y'CbCr layout whose groups are `BYTES` bytes of `PIXELS` pixels (as
/// `group` says) into `dst`.
fn packed_yuv_row<const BYTES: usize, const PIXELS: usize>(
    row: &[u8],
    dst: &mut [[f32; 3]],
    group: PackedYuvGroup,
    to_rgb: &YcbcrToRgb,
) {
    let PackedYuvGroup {
        luma: [y0, y1],
        cb,
        cr,
        ..
    } = group;
    for (g, px) in row.chunks_exact(BYTES).zip(dst.chunks_exact_mut(PIXELS)) {
        if PIXELS == 2 {
            to_rgb.pair([g[y0], g[y1]], g[cb], g[cr], px);
        } else {
            px[0] = to_rgb.pixel(g[y0], g[cb], g[cr]);
        }
    }
}

/// A row of a packed Y'CbCr layout of 16-bit words into `dst`: `Y210`, `Y212` and `Y216`,
/// four words Y0 Cb Y1 Cr for two pixels (the only order V4L2 has for them; fixed here, which
/// makes the loop twice as fast as reading the group's places); the bits below the format's
/// code are not read.
fn packed_yuv16_row(row: &[u8], dst: &mut [[f32; 3]], group: PackedYuvGroup, to_rgb: &YcbcrToRgb) {
    debug_assert_eq!((group.luma, group.cb, group.cr), ([0, 2], 1, 3));
    let mask = to_rgb.word_mask;
    for (g, px) in row.chunks_exact(8).zip(dst.chunks_exact_mut(2)) {
        let [y0, u, y1, v]: [u16; 4] =
            std::array::from_fn(|i| u16::from_le_bytes([g[2 * i], g[2 * i + 1]]) & mask);
        px[0] = to_rgb.pixel16(y0, u, v);
        px[1] = to_rgb.pixel16(y1, u, v);
    }
}

/// Limited-range Y'CbCr → R'G'B' (module doc) for one matrix's (Kr, Kb).
struct YcbcrToRgb {
    /// The bits of a 16-bit word that hold the code (the high `bits`), for the formats of more
    /// than 8 bits ([`Self::pixel16`]).
    word_mask: u16,
    kr: f32,
    kb: f32,
    rv: f32,
    bu: f32,
    kg: f32,
}

impl YcbcrToRgb {
    /// The conversion for a format of `bits` bits a sample (8 to 16).
    fn new((kr, kb): (f32, f32), bits: u8) -> Self {
        Self {
            word_mask: !(u16::MAX.checked_shr(u32::from(bits)).unwrap_or(0)),
            kr,
            kb,
            rv: 2.0 * (1.0 - kr),
            bu: 2.0 * (1.0 - kb),
            kg: 1.0 / (1.0 - kr - kb),
        }
    }

    /// Two pixels that share one chroma pair: their luma codes, Cb and Cr.
    #[inline]
    fn pair(&self, luma: [u8; 2], cb: u8, cr: u8, out: &mut [[f32; 3]]) {
        for (k, luma) in luma.into_iter().enumerate() {
            out[k] = self.pixel(luma, cb, cr);
        }
    }

    /// One pixel: its luma code, Cb and Cr.
    #[inline]
    fn pixel(&self, luma: u8, cb: u8, cr: u8) -> [f32; 3] {
        let u = (f32::from(cb) - 128.0) / 224.0;
        let v = (f32::from(cr) - 128.0) / 224.0;
        let l = (f32::from(luma) - 16.0) / 219.0;
        self.rgb(l, u, v)
    }

    /// One pixel of 16-bit words, the code in their high bits: the limited range scaled by
    /// 256 (BT.2100's 10-bit 64–940 is 4096–60160), so that a word 256·c decodes to the
    /// same bits as the byte c (the scaling by a power of two is exact).
    #[inline]
    fn pixel16(&self, luma: u16, cb: u16, cr: u16) -> [f32; 3] {
        let u = (f32::from(cb) - 32768.0) / 57344.0;
        let v = (f32::from(cr) - 32768.0) / 57344.0;
        let l = (f32::from(luma) - 4096.0) / 56064.0;
        self.rgb(l, u, v)
    }

    #[inline]
    fn rgb(&self, l: f32, u: f32, v: f32) -> [f32; 3] {
        let r = l + self.rv * v;
        let b = l + self.bu * u;
        let g = (l - self.kr * r - self.kb * b) * self.kg;
        [r.clamp(0.0, 1.0), g.clamp(0.0, 1.0), b.clamp(0.0, 1.0)]
    }
}

/// Checks a raw buffer as [`decode_into_on`] does before it decodes: its size, width and
/// stride against its format and length (a JPEG's header and size are checked when it is
/// decoded). A packed buffer that passes decodes without error.
pub fn check(raw: &RawFrame<'_>) -> Result<(), PixelError> {
    check_layout(raw).map(|_| ())
}

/// Where a frame's codes are in its buffer.
enum Layout {
    /// A JPEG stream (its size is checked when it is decoded).
    Jpeg,
    /// `h` rows of `row_bytes` bytes, `stride` bytes apart (for 4:2:0 the luma plane's, and
    /// where the chroma is).
    Packed {
        stride: usize,
        row_bytes: usize,
        chroma: Option<ChromaPlanes>,
    },
}

/// Checks a raw frame's size, width and stride against its format and buffer.
fn check_layout(raw: &RawFrame<'_>) -> Result<Layout, PixelError> {
    let (layout, needed) = frame_layout(raw.format, raw.width, raw.height, raw.stride)?;
    if raw.data.len() < needed {
        return Err(PixelError::Short {
            format: raw.format,
            width: raw.width,
            height: raw.height,
            got: raw.data.len(),
            needed,
        });
    }
    Ok(layout)
}

/// Where the codes of a `w`×`h` frame of `format` with rows `stride` bytes apart (0: packed)
/// are, and how many bytes its buffer needs (0 for a JPEG, whose size is checked when it is
/// decoded); an error for a size or stride the format does not allow.
fn frame_layout(
    format: PixelFormat,
    w: u32,
    h: u32,
    stride: usize,
) -> Result<(Layout, usize), PixelError> {
    let geometry = |message: &str| PixelError::Geometry {
        format,
        width: w,
        height: h,
        message: message.to_string(),
    };
    if w == 0 || h == 0 || u64::from(w) * u64::from(h) > MAX_PIXELS {
        return Err(geometry("frame size must be 1 to 16384² pixels"));
    }
    if format == PixelFormat::Mjpeg {
        return Ok((Layout::Jpeg, 0));
    }
    // Pixels grouped in a row: a YUYV pair, a Bayer pair, a packed group of samples.
    let (group, why) = match format {
        PixelFormat::Csi2Packed { bits: 10, .. } => (
            4,
            "width must be a multiple of 4 (10-bit packed: 4 samples in 5 bytes)",
        ),
        PixelFormat::Csi2Packed { bits: 14, .. } => (
            4,
            "width must be a multiple of 4 (14-bit packed: 4 samples in 7 bytes)",
        ),
        PixelFormat::Csi2Packed { .. } => (
            2,
            "width must be even (12-bit packed: 2 samples in 3 bytes)",
        ),
        PixelFormat::PlanarYuv(layout) if layout.pixels_per_chroma_pair() == 1 => (1, ""),
        PixelFormat::PackedYuv(layout) if layout.group().pixels == 1 => (1, ""),
        PixelFormat::PackedYuv(_) | PixelFormat::PlanarYuv(_) | PixelFormat::Bayer { .. } => {
            (2, "width must be even")
        }
        _ => (1, ""),
    };
    if !w.is_multiple_of(group) {
        return Err(geometry(why));
    }
    if matches!(format, PixelFormat::PlanarYuv(l) if l.rows_per_chroma_row() == 2)
        && !h.is_multiple_of(2)
    {
        return Err(geometry(
            "height must be even (4:2:0 chroma covers 2×2 pixels)",
        ));
    }
    let row_bytes = format.row_bytes(w);
    let stride = if stride == 0 { row_bytes } else { stride };
    if stride < row_bytes {
        return Err(geometry(&format!(
            "stride {stride} is smaller than a row of {row_bytes} bytes"
        )));
    }
    let chroma = match format {
        PixelFormat::PlanarYuv(layout)
            if !layout.interleaved() && layout.pixels_per_chroma_pair() == 2 && stride % 2 != 0 =>
        {
            return Err(geometry(&format!(
                "stride {stride} must be even ({layout:?}: the chroma rows are half as long)"
            )));
        }
        PixelFormat::PlanarYuv(layout) => match layout.chroma(stride, h as usize) {
            Some(chroma) => Some(chroma),
            None => return Err(geometry(&format!("stride {stride} is too large"))),
        },
        _ => None,
    };
    let luma = stride
        .checked_mul(h as usize - 1)
        .and_then(|v| v.checked_add(row_bytes));
    // The last chroma sample of each plane, one past it.
    let chroma_end = |c: ChromaPlanes| {
        let last = (h as usize / c.rows_per - 1).checked_mul(c.stride)?;
        let last = last.checked_add((w as usize / c.pixels_per - 1) * c.step)?;
        c.cb.max(c.cr)
            .checked_add(last)?
            .checked_add(c.sample_bytes)
    };
    let needed = match chroma {
        Some(c) => luma.zip(chroma_end(c)).map(|(a, b)| a.max(b)),
        None => luma,
    };
    let Some(needed) = needed else {
        return Err(geometry(&format!("stride {stride} is too large")));
    };
    let layout = Layout::Packed {
        stride,
        row_bytes,
        chroma,
    };
    Ok((layout, needed))
}

/// Mirror index without repeating the edge: −1 → 1, n → n − 2 (n = 1: 0).
#[inline]
fn mirror(i: isize, n: usize) -> usize {
    let n = n as isize;
    let j = if i < 0 {
        -i
    } else if i >= n {
        2 * n - 2 - i
    } else {
        i
    };
    j.clamp(0, n - 1) as usize
}

/// Bilinear demosaic: missing colours are the mean of that colour's samples in the 3×3
/// neighbourhood (mirrored borders). At a red or blue site that is the 4 edge neighbours for
/// green and the 4 diagonals for the other colour; at a green site the 2 horizontal and the 2
/// vertical neighbours for the two other colours. Mirroring keeps the colour phase, so the same
/// stencils hold at the border with mirrored indices.
pub fn demosaic_bilinear(
    mosaic: &[f32],
    w: usize,
    h: usize,
    pattern: BayerPattern,
    out: &mut [[f32; 3]],
) {
    demosaic_bilinear_on(mosaic, w, h, pattern, out, None);
}

/// [`demosaic_bilinear`] with bands of rows in parallel on `pool` (`None`: the calling thread).
fn demosaic_bilinear_on(
    mosaic: &[f32],
    w: usize,
    h: usize,
    pattern: BayerPattern,
    out: &mut [[f32; 3]],
    pool: Option<&rayon::ThreadPool>,
) {
    if w == 0 || h == 0 || mosaic.len() < w * h || out.len() < w * h {
        return;
    }
    let read_row = |y: usize, dst: &mut [f32]| dst.copy_from_slice(&mosaic[y * w..][..w]);
    demosaic_rows(w, h, pattern, read_row, out, pool);
}

/// The bilinear demosaic of a `w`×`h` mosaic whose row y `read_row(y, row)` writes, in bands of
/// [`ROWS_PER_TASK`] rows on the calling thread and `pool`'s: a band reads its rows and the
/// (mirrored) rows above and below it into a buffer of its own, which stays in the cache, and
/// demosaics each row from there, the interior pixels with [`BayerRows::interior`]'s kernels.
fn demosaic_rows(
    w: usize,
    h: usize,
    pattern: BayerPattern,
    read_row: impl Fn(usize, &mut [f32]) + Sync,
    out: &mut [[f32; 3]],
    pool: Option<&rayon::ThreadPool>,
) {
    if w == 0 || h == 0 || out.len() < w * h {
        return;
    }
    crate::parallel::for_each_chunk_mut(
        pool,
        &mut out[..w * h],
        ROWS_PER_TASK * w,
        |band, out_rows| demosaic_band(w, h, pattern, &read_row, band * ROWS_PER_TASK, out_rows),
    );
}

/// The rows `y0`, `y0 + 1`, … of [`demosaic_rows`] into `out_rows` (whole rows of width `w`):
/// the band's rows and the (mirrored) rows above and below it are read into a buffer of its
/// own and each row is demosaiced from there.
fn demosaic_band(
    w: usize,
    h: usize,
    pattern: BayerPattern,
    read_row: impl Fn(usize, &mut [f32]),
    y0: usize,
    out_rows: &mut [[f32; 3]],
) {
    if w == 0 || h == 0 {
        return;
    }
    let n = out_rows.len() / w;
    with_scratch(&BAND_MOSAIC, (n + 2) * w, |local| {
        // Local row k holds image row y0 + k − 1, mirrored at the top and bottom; every row
        // is read before it is used.
        for (k, dst) in local.chunks_exact_mut(w).enumerate() {
            read_row(mirror((y0 + k) as isize - 1, h), dst);
        }
        demosaic_band_rows(w, pattern, local, y0, out_rows);
    });
}

/// [`demosaic_band`]'s rows from `local`, which holds the band's mosaic rows and the ones
/// above and below it.
fn demosaic_band_rows(
    w: usize,
    pattern: BayerPattern,
    local: &[f32],
    y0: usize,
    out_rows: &mut [[f32; 3]],
) {
    for (r, out_row) in out_rows.chunks_exact_mut(w).enumerate() {
        let y = y0 + r;
        let rows = BayerRows {
            up: &local[r * w..][..w],
            row: &local[(r + 1) * w..][..w],
            down: &local[(r + 2) * w..][..w],
        };
        // The row's red or blue colour, and whether its even columns are green.
        let even = pattern.channel(0, y);
        let green_first = even == 1;
        let other = if green_first {
            pattern.channel(1, y)
        } else {
            even
        };
        // Interior pixels: neighbours without mirroring, in pairs of fixed colours (one
        // kernel per row kind, the colours as constants).
        match (other, green_first) {
            (0, false) => rows.interior::<0, false>(out_row),
            (0, true) => rows.interior::<0, true>(out_row),
            (_, false) => rows.interior::<2, false>(out_row),
            (_, true) => rows.interior::<2, true>(out_row),
        }
        // The border columns, with mirrored neighbours.
        for x in [0, w - 1] {
            out_row[x] = rows.pixel(pattern, x, y);
        }
    }
}

/// The three mosaic rows one output row of the bilinear demosaic reads (mirrored at the top and
/// bottom), each exactly the image's width.
struct BayerRows<'a> {
    up: &'a [f32],
    row: &'a [f32],
    down: &'a [f32],
}

impl BayerRows<'_> {
    /// One pixel, any column (mirrored left and right neighbours at the borders): the
    /// definition the interior kernel follows, summing in the same order (so the same bits).
    fn pixel(&self, pattern: BayerPattern, x: usize, y: usize) -> [f32; 3] {
        let w = self.row.len();
        let (l, r) = (mirror(x as isize - 1, w), mirror(x as isize + 1, w));
        let (up, row, down) = (self.up, self.row, self.down);
        let own = pattern.channel(x, y);
        let mut px = [0.0f32; 3];
        px[own] = row[x];
        if own != 1 {
            px[1] = 0.25 * (row[l] + row[r] + up[x] + down[x]);
            px[2 - own] = 0.25 * (up[l] + up[r] + down[l] + down[r]);
        } else {
            let horizontal = pattern.channel(x + 1, y);
            px[horizontal] = 0.5 * (row[l] + row[r]);
            px[2 - horizontal] = 0.5 * (up[x] + down[x]);
        }
        px
    }

    /// Columns 1..w − 1 of a row whose red or blue colour is `OTHER` (0 or 2) and whose even
    /// columns are green if `GREEN_FIRST`, without bounds checks in the loop. With them (and the
    /// bands' own code buffers) a 1280×960 Bayer frame decodes in about a fifth of the time
    /// the per-pixel stencil took (docs/performance.md, "Camera conversions").
    fn interior<const OTHER: usize, const GREEN_FIRST: bool>(&self, out: &mut [[f32; 3]]) {
        let w = self.row.len();
        if w < 3 || out.len() != w {
            return;
        }
        let (up, row, down) = (self.up, self.row, self.down);
        // Pairs of columns x, x + 1 from x = 1, which is odd: green unless the even columns
        // are. Each reads columns x − 1 ..= x + 2 of the three rows (windows of 4 from column 0,
        // every second one), so the loop needs no index checks.
        let mut pairs = out[1..w - 1].chunks_exact_mut(2);
        let rows = up
            .windows(4)
            .step_by(2)
            .zip(row.windows(4).step_by(2))
            .zip(down.windows(4).step_by(2));
        for (pair, ((u, r), d)) in (&mut pairs).zip(rows) {
            let (u, r, d) = (window4(u), window4(r), window4(d));
            if GREEN_FIRST {
                pair[0] = bayer_colour_site::<OTHER>(
                    [u[0], u[1], u[2]],
                    [r[0], r[1], r[2]],
                    [d[0], d[1], d[2]],
                );
                pair[1] = bayer_green_site::<OTHER>(u[2], [r[1], r[2], r[3]], d[2]);
            } else {
                pair[0] = bayer_green_site::<OTHER>(u[1], [r[0], r[1], r[2]], d[1]);
                pair[1] = bayer_colour_site::<OTHER>(
                    [u[1], u[2], u[3]],
                    [r[1], r[2], r[3]],
                    [d[1], d[2], d[3]],
                );
            }
        }
        // An odd width leaves column w − 2, which is odd.
        if let [last] = pairs.into_remainder() {
            let x = w - 2;
            let three = |r: &[f32]| [r[x - 1], r[x], r[x + 1]];
            *last = if GREEN_FIRST {
                bayer_colour_site::<OTHER>(three(up), three(row), three(down))
            } else {
                bayer_green_site::<OTHER>(up[x], three(row), down[x])
            };
        }
    }
}

/// The first four values of a window of four.
#[inline(always)]
fn window4(c: &[f32]) -> [f32; 4] {
    [c[0], c[1], c[2], c[3]]
}

/// A green site of a row whose red or blue colour is `OTHER`: that colour from the left and
/// right neighbours, the third from above and below (`row`: left, own, right).
#[inline(always)]
fn bayer_green_site<const OTHER: usize>(up: f32, row: [f32; 3], down: f32) -> [f32; 3] {
    let mut px = [0.0f32; 3];
    px[1] = row[1];
    px[OTHER] = 0.5 * (row[0] + row[2]);
    px[2 - OTHER] = 0.5 * (up + down);
    px
}

/// A site of colour `OTHER` (red or blue): green from the four edge neighbours, the third
/// colour from the four diagonals (each row: left, centre, right).
#[inline(always)]
fn bayer_colour_site<const OTHER: usize>(up: [f32; 3], row: [f32; 3], down: [f32; 3]) -> [f32; 3] {
    let mut px = [0.0f32; 3];
    px[OTHER] = row[1];
    px[1] = 0.25 * (row[0] + row[2] + up[1] + down[1]);
    px[2 - OTHER] = 0.25 * (up[0] + up[2] + down[0] + down[2]);
    px
}

/// Input rows per parallel task of the conversions: 32 rows of a 1280-wide frame are 41k pixels.
const ROWS_PER_TASK: usize = 32;

/// Calls `f(y, row)` for every row (`width` elements) of `image`: in order on the calling
/// thread without a pool, else in bands of rows on the calling thread and `pool`'s threads
/// together (the camera source's conversion helpers; src/parallel.rs). Every pixel is
/// converted by itself, so the result does not depend on which thread converts it.
fn each_row<T: Send>(
    pool: Option<&rayon::ThreadPool>,
    image: &mut [T],
    width: usize,
    f: impl Fn(usize, &mut [T]) + Sync,
) {
    if width == 0 {
        return;
    }
    let rows = image.len() / width;
    crate::parallel::for_each_chunk_mut(
        pool,
        &mut image[..rows * width],
        ROWS_PER_TASK * width,
        |band, rows| {
            for (r, row) in rows.chunks_exact_mut(width).enumerate() {
                f(band * ROWS_PER_TASK + r, row);
            }
        },
    );
}

/// Whether a JPEG stream defines Huffman tables (a DHT segment before the first scan). Many
/// UVC cameras send MJPEG frames without them, relying on the standard tables of JPEG Annex K
/// (as Motion-JPEG/AVI does).
fn has_huffman_tables(data: &[u8]) -> bool {
    let mut pos = 2; // after SOI
    while pos + 4 <= data.len() {
        if data[pos] != 0xFF {
            return true; // malformed: let the decoder report it
        }
        match data[pos + 1] {
            0xC4 => return true,
            0xDA => return false,
            0xFF => pos += 1, // fill byte
            _ => {
                let len = usize::from(u16::from_be_bytes([data[pos + 2], data[pos + 3]]));
                pos += 2 + len;
            }
        }
    }
    true
}

/// Decodes a JPEG stream of a `w`×`h` frame into 8-bit RGB: `3·w·h` bytes in `bytes`, whose
/// allocation is reused. Every byte is written: zune-jpeg decodes every block even of a stream
/// cut short (tested: `truncated_mjpeg_into_a_used_buffer_equals_a_fresh_decode`).
fn decode_jpeg_rgb8(data: &[u8], w: u32, h: u32, bytes: &mut Vec<u8>) -> Result<(), PixelError> {
    // A frame without Huffman tables gets an "AVI1" APP0 segment after its SOI, which tells
    // zune-jpeg to use the standard Motion-JPEG tables.
    let patched;
    let data = if data.starts_with(&[0xFF, 0xD8]) && !has_huffman_tables(data) {
        let mut v = Vec::with_capacity(data.len() + 10);
        v.extend_from_slice(&[
            0xFF, 0xD8, 0xFF, 0xE0, 0x00, 0x08, b'A', b'V', b'I', b'1', 0, 0,
        ]);
        v.extend_from_slice(&data[2..]);
        patched = v;
        &patched[..]
    } else {
        data
    };
    use zune_jpeg::zune_core::bytestream::ZCursor;
    use zune_jpeg::zune_core::colorspace::ColorSpace;
    use zune_jpeg::zune_core::options::DecoderOptions;
    let options = DecoderOptions::default()
        .jpeg_set_out_colorspace(ColorSpace::RGB)
        .set_max_width(16384)
        .set_max_height(16384);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(data), options);
    let zune = |e: zune_jpeg::errors::DecodeErrors| PixelError::Jpeg(format!("{e:?}"));
    // zune-jpeg returns errors on corrupt data; a panic on some input is still caught.
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        decoder.decode_headers().map_err(zune)?;
        let (jw, jh) = decoder
            .dimensions()
            .ok_or_else(|| PixelError::Jpeg("no image header".into()))?;
        if (jw, jh) != (w as usize, h as usize) {
            return Err(PixelError::Jpeg(format!(
                "image is {jw}x{jh}, the negotiated frame size is {w}x{h}"
            )));
        }
        let n = 3 * w as usize * h as usize;
        if decoder.output_buffer_size() != Some(n) {
            return Err(PixelError::Jpeg(format!(
                "decoder wants {:?} bytes for {n} RGB samples",
                decoder.output_buffer_size()
            )));
        }
        // Every byte is written by the decoder: a buffer of the right size is reused as it is.
        bytes.resize(n, 0);
        decoder.decode_into(bytes).map_err(zune)
    }))
    .map_err(|_| PixelError::Jpeg("the decoder panicked on corrupt data".into()))?
}

/// A JPEG stream → normalised codes: [`decode_jpeg_rgb8`], then b / 255 for every byte.
fn decode_jpeg(
    data: &[u8],
    w: u32,
    h: u32,
    out: &mut CodeImage,
    pool: Option<&rayon::ThreadPool>,
) -> Result<(), PixelError> {
    let mut image = ByteImage {
        width: w,
        height: h,
        channels: 3,
        bytes: Vec::new(),
    };
    decode_jpeg_rgb8(data, w, h, &mut image.bytes)?;
    image.to_codes_into_on(out, pool);
    Ok(())
}

/// Pseudo-random bytes (the top byte of a 64-bit LCG) from `seed`: the test frames of the
/// capture modules.
#[cfg(test)]
pub(crate) fn byte_stream(mut state: u64) -> impl FnMut() -> u8 {
    move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1);
        (state >> 56) as u8
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raw(data: &[u8], format: PixelFormat, w: u32, h: u32) -> RawFrame<'_> {
        RawFrame {
            data,
            format,
            width: w,
            height: h,
            stride: 0,
        }
    }

    fn close(a: [f32; 3], b: [f32; 3], tol: f32) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
    }

    #[test]
    fn fourcc_round_trip_and_names() {
        for f in PixelFormat::all() {
            assert_eq!(PixelFormat::from_fourcc(f.fourcc()), Some(f), "{f}");
            assert_eq!(PixelFormat::parse(&f.to_string()), Some(f), "{f}");
        }
        assert_eq!(
            PixelFormat::parse("Y16"),
            Some(PixelFormat::Grey { bits: 16 })
        );
        assert_eq!(PixelFormat::parse("mjpeg"), Some(PixelFormat::Mjpeg));
        assert_eq!(
            PixelFormat::parse("nv12"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Nv12))
        );
        assert_eq!(
            PixelFormat::parse("I420"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Yu12))
        );
        assert_eq!(
            PixelFormat::parse("nv24"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Nv24))
        );
        assert_eq!(
            PixelFormat::parse("ayuv"),
            Some(PixelFormat::PackedYuv(PackedYuv::Ayuv32))
        );
        assert_eq!(
            PixelFormat::parse("YUV3"),
            Some(PixelFormat::PackedYuv(PackedYuv::Yuv24))
        );
        assert_eq!(PixelFormat::parse("YUV4"), None);
        assert_eq!(
            PixelFormat::parse("422p"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Yuv422p))
        );
        // The separate-plane codes of multi-planar nodes, as `envlight devices` shows them.
        assert_eq!(
            PixelFormat::parse("NM12"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Nv12))
        );
        assert_eq!(
            PixelFormat::parse("ym21"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Yv12))
        );
        assert_eq!(
            PixelFormat::parse("rg12"),
            Some(PixelFormat::Bayer {
                pattern: BayerPattern::Rggb,
                bits: 12
            })
        );
        assert_eq!(PixelFormat::parse(""), None);
        assert_eq!(PixelFormat::parse("TOOLONG"), None);
        assert_eq!(PixelFormat::Grey { bits: 12 }.code_max(), 4095.0);
    }

    /// Every MIPI CSI-2 packed layout decodes to the same codes, to the bit, as the unpacked
    /// layout of the same samples (Bayer `RG10` …, grey `Y10 `/`Y12 `), packed rows or padded;
    /// the bit order of a packed group; the width rules.
    #[test]
    fn csi2_packed_raw_equals_the_unpacked_layout() {
        let (w, h) = (12usize, 6usize);
        let mut byte = byte_stream(0xc512_0a0a);
        for &(pattern, bits, _) in &CSI2_FOURCCS {
            let max = (1u16 << bits) - 1;
            let samples: Vec<u16> = (0..w * h)
                .map(|_| u16::from_le_bytes([byte(), byte()]) & max)
                .collect();
            let unpacked: Vec<u8> = samples.iter().flat_map(|v| v.to_le_bytes()).collect();
            let unpacked_format = match pattern {
                Some(pattern) => PixelFormat::Bayer { pattern, bits },
                None => PixelFormat::Grey { bits },
            };
            let (w32, h32) = (w as u32, h as u32);
            let expected =
                decode(&raw(&unpacked, unpacked_format, w32, h32), YuvMatrix::Auto).unwrap();
            let format = PixelFormat::Csi2Packed { pattern, bits };
            let row_bytes = format.row_bytes(w32);
            for padding in [0, 7] {
                let mut data = Vec::new();
                for row in samples.chunks(w) {
                    if bits == 10 {
                        for s in row.chunks(4) {
                            data.extend(s.iter().map(|v| (v >> 2) as u8));
                            data.push(
                                s.iter()
                                    .enumerate()
                                    .fold(0u8, |low, (k, v)| low | (((v & 0b11) as u8) << (2 * k))),
                            );
                        }
                    } else if bits == 14 {
                        // Byte by byte as Linux's pixfmt-srggb14p table draws them.
                        for s in row.chunks(4) {
                            let low = |k: usize| (s[k] & 0x3F) as u8;
                            data.extend(s.iter().map(|v| (v >> 6) as u8));
                            data.push(low(0) | (low(1) & 0b11) << 6);
                            data.push(low(1) >> 2 | (low(2) & 0xF) << 4);
                            data.push(low(2) >> 4 | low(3) << 2);
                        }
                    } else {
                        for s in row.chunks(2) {
                            data.extend([(s[0] >> 4) as u8, (s[1] >> 4) as u8]);
                            data.push((s[0] & 0xF) as u8 | (((s[1] & 0xF) as u8) << 4));
                        }
                    }
                    data.resize(data.len() + padding, 0xA5);
                }
                assert_eq!(data.len(), h * (row_bytes + padding), "{format}");
                let frame = RawFrame {
                    stride: row_bytes + padding,
                    ..raw(&data, format, w32, h32)
                };
                let got = decode(&frame, YuvMatrix::Auto).unwrap();
                assert!(
                    got.pixels.iter().flatten().map(|v| v.to_bits()).eq(expected
                        .pixels
                        .iter()
                        .flatten()
                        .map(|v| v.to_bits())),
                    "{format} padding {padding}"
                );
            }
        }
        // Bit order: 10-bit samples 0x3FF, 0x001, 0x200, 0x155 and 12-bit 0xABC, 0x123.
        let y10p = PixelFormat::Csi2Packed {
            pattern: None,
            bits: 10,
        };
        let group = [0xFF, 0x00, 0x80, 0x55, 0b01_00_01_11];
        let img = decode(&raw(&group, y10p, 4, 1), YuvMatrix::Auto).unwrap();
        let codes: Vec<f32> = img.pixels.iter().map(|p| p[0] * 1023.0).collect();
        for (got, want) in codes.iter().zip([0x3FF, 0x001, 0x200, 0x155]) {
            assert!((got - f32::from(want as u16)).abs() < 1e-3, "{codes:?}");
        }
        let y12p = PixelFormat::Csi2Packed {
            pattern: None,
            bits: 12,
        };
        let img = decode(&raw(&[0xAB, 0x12, 0x3C], y12p, 2, 1), YuvMatrix::Auto).unwrap();
        let codes: Vec<f32> = img.pixels.iter().map(|p| p[0] * 4095.0).collect();
        for (got, want) in codes.iter().zip([0xABC, 0x123]) {
            assert!((got - f32::from(want as u16)).abs() < 1e-3, "{codes:?}");
        }
        // 14-bit samples 0x3FFF, 0x0001, 0x2000, 0x1555: high bytes, then the low 6-bit parts
        // 0x3F, 0x01, 0x00, 0x15 from bit 0 of byte 4 on.
        let y14p = PixelFormat::Csi2Packed {
            pattern: None,
            bits: 14,
        };
        let group = [0xFF, 0x00, 0x80, 0x55, 0x7F, 0x00, 0x54];
        let img = decode(&raw(&group, y14p, 4, 1), YuvMatrix::Auto).unwrap();
        let codes: Vec<f32> = img.pixels.iter().map(|p| p[0] * 16383.0).collect();
        for (got, want) in codes.iter().zip([0x3FFF, 0x0001, 0x2000, 0x1555]) {
            assert!((got - f32::from(want as u16)).abs() < 1e-2, "{codes:?}");
        }
        assert_eq!(y14p.row_bytes(8), 14);
        // Widths the packing does not allow.
        let e = decode(&raw(&[0; 64], y14p, 6, 2), YuvMatrix::Auto).unwrap_err();
        assert!(e.to_string().contains("14-bit packed"), "{e}");
        let e = decode(&raw(&[0; 64], y10p, 6, 2), YuvMatrix::Auto).unwrap_err();
        assert!(e.to_string().contains("multiple of 4"), "{e}");
        let e = decode(&raw(&[0; 64], y12p, 3, 2), YuvMatrix::Auto).unwrap_err();
        assert!(e.to_string().contains("even"), "{e}");
        let e = decode(&raw(&[0; 9], y12p, 4, 2), YuvMatrix::Auto).unwrap_err();
        assert!(e.to_string().contains("needs 12"), "{e}");
        // The codes that differ in case only are two layouts.
        assert_eq!(
            PixelFormat::parse("pgAA"),
            Some(PixelFormat::Csi2Packed {
                pattern: Some(BayerPattern::Grbg),
                bits: 10
            })
        );
        assert_eq!(
            PixelFormat::parse("pGAA"),
            Some(PixelFormat::Csi2Packed {
                pattern: Some(BayerPattern::Gbrg),
                bits: 10
            })
        );
        assert_eq!(PixelFormat::parse("y10p"), Some(y10p));
        assert_eq!(PixelFormat::parse("Y14P"), Some(y14p));
        assert_eq!(
            PixelFormat::parse("pREE"),
            Some(PixelFormat::Csi2Packed {
                pattern: Some(BayerPattern::Rggb),
                bits: 14
            })
        );
        assert_eq!(
            PixelFormat::parse("RG14"),
            Some(PixelFormat::Bayer {
                pattern: BayerPattern::Rggb,
                bits: 14
            })
        );
        assert_eq!(
            PixelFormat::parse("Y14"),
            Some(PixelFormat::Grey { bits: 14 })
        );
    }

    /// Every packed Y'CbCr layout (4:2:2 and 4:4:4, with and without row padding) decodes to
    /// the same bits as YUYV carrying the same samples (for 4:4:4 each chroma pair on the two
    /// pixels of the YUYV pair); alpha and padding bytes are not read; 4:4:4 takes an odd
    /// width (the same bits as NV24), 4:2:2 does not; a short buffer is an error.
    #[test]
    fn packed_yuv_layouts_equal_yuyv_with_the_same_samples() {
        let (w, h) = (6usize, 3usize);
        let mut byte = byte_stream(0x9ac4_e700);
        let samples: Vec<u8> = (0..w * h * 2).map(|_| byte()).collect();
        let bits = |img: &CodeImage| -> Vec<u32> {
            img.pixels.iter().flatten().map(|v| v.to_bits()).collect()
        };
        let yuyv = PixelFormat::PackedYuv(PackedYuv::Yuyv);
        let (w32, h32) = (w as u32, h as u32);
        let expected = bits(&decode(&raw(&samples, yuyv, w32, h32), YuvMatrix::Bt601).unwrap());
        // The bytes of a YUYV group's two pixels in `layout` (Linux's pixfmt-packed-yuv tables),
        // `a` an alpha or padding byte.
        let group = |layout: PackedYuv, [y0, cb, y1, cr]: [u8; 4], a: u8| -> Vec<u8> {
            let each = |f: &dyn Fn(u8) -> Vec<u8>| [f(y0), f(y1)].concat();
            match layout {
                PackedYuv::Yuyv => vec![y0, cb, y1, cr],
                PackedYuv::Uyvy => vec![cb, y0, cr, y1],
                PackedYuv::Yvyu => vec![y0, cr, y1, cb],
                PackedYuv::Vyuy => vec![cr, y0, cb, y1],
                PackedYuv::Yuv24 => each(&|y| vec![y, cb, cr]),
                PackedYuv::Ayuv32 | PackedYuv::Xyuv32 => each(&|y| vec![a, y, cb, cr]),
                PackedYuv::Vuya32 | PackedYuv::Vuyx32 => each(&|y| vec![cr, cb, y, a]),
                PackedYuv::Yuva32 | PackedYuv::Yuvx32 => each(&|y| vec![y, cb, cr, a]),
                // Each sample as the word 256·c, with bits below the code that must not be
                // read (none for 16-bit codes).
                PackedYuv::Y210 | PackedYuv::Y212 | PackedYuv::Y216 => {
                    let below_code = u16::MAX.checked_shr(layout.bits().into()).unwrap_or(0);
                    let low = a & below_code as u8;
                    [y0, cb, y1, cr].iter().flat_map(|&c| [low, c]).collect()
                }
            }
        };
        for layout in PackedYuv::ALL {
            let format = PixelFormat::PackedYuv(layout);
            let row_bytes = format.row_bytes(w32);
            for padding in [0, 5] {
                let mut data = Vec::new();
                for row in samples.chunks(2 * w) {
                    for quad in row.chunks(4) {
                        data.extend(group(layout, quad.try_into().unwrap(), byte()));
                    }
                    data.resize(data.len() + padding, 0xEE);
                }
                assert_eq!(data.len(), h * (row_bytes + padding), "{format}");
                let stride = row_bytes + padding;
                let frame = RawFrame {
                    stride,
                    ..raw(&data, format, w32, h32)
                };
                let got = decode(&frame, YuvMatrix::Bt601).unwrap();
                assert_eq!(bits(&got), expected, "{format} padding {padding}");
                let needed = format.buffer_len(w32, h32, stride).unwrap();
                assert_eq!(needed, data.len() - padding, "{format}");
                let short = RawFrame {
                    data: &data[..needed - 1],
                    ..frame
                };
                let e = decode(&short, YuvMatrix::Bt601).unwrap_err();
                assert!(e.to_string().contains(&format!("needs {needed}")), "{e}");
            }
            // A row of 3 pixels: 4:4:4 as NV24 of its samples, 4:2:2 refused.
            let odd = [(81u8, 90u8, 240u8), (41, 240, 110), (235, 128, 128)];
            if layout.group().pixels == 1 {
                let data: Vec<u8> = odd
                    .iter()
                    .flat_map(|&(y, cb, cr)| {
                        group(layout, [y, cb, y, cr], 7)[..row_bytes / w].to_vec()
                    })
                    .collect();
                let mut nv24: Vec<u8> = odd.iter().map(|s| s.0).collect();
                nv24.extend(odd.iter().flat_map(|&(_, cb, cr)| [cb, cr]));
                let nv24_format = PixelFormat::PlanarYuv(PlanarYuv::Nv24);
                let want = decode(&raw(&nv24, nv24_format, 3, 1), YuvMatrix::Bt601).unwrap();
                let got = decode(&raw(&data, format, 3, 1), YuvMatrix::Bt601).unwrap();
                assert_eq!(bits(&got), bits(&want), "{format} of width 3");
            } else {
                let e = decode(&raw(&[0; 64], format, 3, 1), YuvMatrix::Bt601).unwrap_err();
                assert!(
                    e.to_string().contains("width must be even"),
                    "{format}: {e}"
                );
            }
        }
    }

    /// 10-bit codes keep their precision: BT.2100's limited range (64 black, 940 white, 512 no
    /// chroma) in the high bits of P010's and Y210's words gives (Y − 64)/876 for grey, codes
    /// one apart differ, and a 12-bit P012 code likewise ((Y − 256)/3504).
    #[test]
    fn ten_and_twelve_bit_yuv_keep_their_precision() {
        let grey = |y10: u16| (f32::from(y10) - 64.0) / 876.0;
        let packed = PixelFormat::PackedYuv(PackedYuv::Y210);
        let planar = PixelFormat::PlanarYuv(PlanarYuv::P010);
        for y10 in [64u16, 65, 66, 502, 939, 940] {
            let w = |c: u16| (c << 6).to_le_bytes();
            // Y210: Y0 Cb Y1 Cr; P010 2 × 2: four luma words, then a Cb, Cr pair.
            let y210: Vec<u8> = [y10, 512, y10, 512].iter().flat_map(|&c| w(c)).collect();
            let p010: Vec<u8> = [y10, y10, y10, y10, 512, 512]
                .iter()
                .flat_map(|&c| w(c))
                .collect();
            for (data, format, h) in [(&y210, packed, 1), (&p010, planar, 2)] {
                let img = decode(&raw(data, format, 2, h), YuvMatrix::Bt2020).unwrap();
                for p in &img.pixels {
                    assert!(close(*p, [grey(y10); 3], 1e-6), "{format} {y10}: {p:?}");
                }
            }
        }
        let p012 = PixelFormat::PlanarYuv(PlanarYuv::P012);
        let w = |c: u16| (c << 4).to_le_bytes();
        let data: Vec<u8> = [257u16, 257, 257, 257, 2048, 2048]
            .iter()
            .flat_map(|&c| w(c))
            .collect();
        let img = decode(&raw(&data, p012, 2, 2), YuvMatrix::Bt709).unwrap();
        assert!(close(img.pixels[3], [1.0 / 3504.0; 3], 1e-9), "{img:?}");
        assert_eq!(p012.bits(), 12);
        assert_eq!(PixelFormat::PackedYuv(PackedYuv::Y216).code_max(), 65535.0);
        // Odd sizes are refused as for NV12 and YUYV.
        for (format, w, h) in [(planar, 2, 3), (planar, 3, 2), (packed, 3, 1)] {
            assert!(decode(&raw(&[0; 64], format, w, h), YuvMatrix::Auto).is_err());
        }
    }

    /// UYVY and the nine planar layouts (4:2:0, 4:2:2 and 4:4:4) of one image (with and without
    /// row padding) decode to the same bits as YUYV carrying the same samples (for 4:2:0 each
    /// chroma pair repeated on the two rows it covers, for 4:4:4 on the two pixels of the
    /// YUYV pair), which the known-value test below pins;
    /// known values for black, white and BT.601 red; and their buffers are checked.
    #[test]
    fn uyvy_and_planar_layouts_equal_yuyv_with_the_same_samples() {
        let (w, h) = (6usize, 4usize);
        let mut byte = byte_stream(0x5eed_4200);
        let luma: Vec<u8> = (0..w * h).map(|_| byte()).collect();
        // Chroma samples for a chroma row per luma row; 4:2:0 uses the first h/2 rows.
        let cb_all: Vec<u8> = (0..w * h / 2).map(|_| byte()).collect();
        let cr_all: Vec<u8> = (0..w * h / 2).map(|_| byte()).collect();
        let (w32, h32) = (w as u32, h as u32);
        let bits = |img: &CodeImage| -> Vec<u32> {
            img.pixels.iter().flatten().map(|v| v.to_bits()).collect()
        };
        // YUYV carrying the samples of chroma subsampled by `rows_per` rows.
        let yuyv_of = |rows_per: usize| {
            let chroma_at =
                |plane: &[u8], x: usize, y: usize| plane[(y / rows_per) * (w / 2) + x / 2];
            let mut yuyv = Vec::new();
            for y in 0..h {
                for x in (0..w).step_by(2) {
                    yuyv.extend([
                        luma[y * w + x],
                        chroma_at(&cb_all, x, y),
                        luma[y * w + x + 1],
                        chroma_at(&cr_all, x, y),
                    ]);
                }
            }
            yuyv
        };
        let yuyv = yuyv_of(2);
        let expected = decode(
            &raw(&yuyv, PixelFormat::PackedYuv(PackedYuv::Yuyv), w32, h32),
            YuvMatrix::Bt601,
        )
        .unwrap();
        // UYVY: the same samples in the order U Y0 V Y1.
        let uyvy: Vec<u8> = yuyv
            .chunks(4)
            .flat_map(|q| [q[1], q[0], q[3], q[2]])
            .collect();
        let got = decode(
            &raw(&uyvy, PixelFormat::PackedYuv(PackedYuv::Uyvy), w32, h32),
            YuvMatrix::Bt601,
        )
        .unwrap();
        assert_eq!(bits(&got), bits(&expected), "UYVY");
        // A layout's buffer with luma rows `stride` bytes apart (padding bytes 0xEE).
        let buffer = |layout: PlanarYuv, stride: usize| {
            let rows = h / layout.rows_per_chroma_row();
            let (cb, cr) = (&cb_all[..rows * w / 2], &cr_all[..rows * w / 2]);
            let mut data = Vec::new();
            for row in luma.chunks(w) {
                data.extend(row);
                data.resize(data.len() + stride - w, 0xEE);
            }
            // Pairs per chroma row: w / 2, or w for 4:4:4 (each sample for both pixels of
            // the YUYV pair), the rows `stride` (4:4:4: 2 × stride) bytes apart; a plane's
            // rows stride / 2 (4:4:4: stride) apart.
            let repeat = 2 / layout.pixels_per_chroma_pair();
            let plane_stride = stride * repeat / 2;
            let plane = |samples: &[u8]| {
                let mut out = Vec::new();
                for row in samples.chunks(w / 2) {
                    let row: Vec<u8> = row.iter().flat_map(|&c| [c].repeat(repeat)).collect();
                    out.extend(&row);
                    out.resize(out.len() + plane_stride - row.len(), 0xEE);
                }
                out
            };
            let interleave = |first: &[u8], second: &[u8]| {
                let pairs: Vec<u8> = first
                    .iter()
                    .zip(second)
                    .flat_map(|(&a, &b)| [a, b].repeat(repeat))
                    .collect();
                let mut out = Vec::new();
                for row in pairs.chunks(w * repeat) {
                    out.extend(row);
                    out.resize(out.len() + (stride - w) * repeat, 0xEE);
                }
                out
            };
            match layout {
                PlanarYuv::Nv12
                | PlanarYuv::Nv16
                | PlanarYuv::Nv24
                | PlanarYuv::P010
                | PlanarYuv::P012 => data.extend(interleave(cb, cr)),
                PlanarYuv::Nv21 | PlanarYuv::Nv61 | PlanarYuv::Nv42 => {
                    data.extend(interleave(cr, cb))
                }
                PlanarYuv::Yu12 | PlanarYuv::Yuv422p | PlanarYuv::Yuv444p => {
                    data.extend([plane(cb), plane(cr)].concat())
                }
                PlanarYuv::Yv12 | PlanarYuv::Yvu422p | PlanarYuv::Yvu444p => {
                    data.extend([plane(cr), plane(cb)].concat())
                }
            }
            data
        };
        for layout in PlanarYuv::ALL {
            let format = PixelFormat::PlanarYuv(layout);
            let expected = decode(
                &raw(
                    &yuyv_of(layout.rows_per_chroma_row()),
                    PixelFormat::PackedYuv(PackedYuv::Yuyv),
                    w32,
                    h32,
                ),
                YuvMatrix::Bt601,
            )
            .unwrap();
            for samples_stride in [w, w + 4] {
                // P010 and P012: each byte b of the NV12 buffer as the word 256·b, plus
                // bits below the code that must not be read.
                let sample = layout.sample_bytes();
                let below_code = u16::MAX.checked_shr(layout.bits().into()).unwrap_or(0) as u8;
                let data: Vec<u8> = if sample == 2 {
                    let mut byte = byte_stream(0x10b1_7500);
                    let bytes = buffer(layout, samples_stride).into_iter();
                    bytes.flat_map(|b| [byte() & below_code, b]).collect()
                } else {
                    buffer(layout, samples_stride)
                };
                let stride = samples_stride * sample;
                let frame = RawFrame {
                    stride,
                    ..raw(&data, format, w32, h32)
                };
                let got = decode(&frame, YuvMatrix::Bt601).unwrap();
                assert_eq!(bits(&got), bits(&expected), "{format} stride {stride}");
                // The last row's padding is not needed.
                let needed = format.buffer_len(w32, h32, stride).unwrap();
                let last_padding = sample
                    * if layout.interleaved() {
                        (samples_stride - w) * 2 / layout.pixels_per_chroma_pair()
                    } else {
                        (samples_stride - w) / layout.pixels_per_chroma_pair()
                    };
                assert_eq!(
                    needed,
                    data.len() - last_padding,
                    "{format} stride {stride}"
                );
                let short = RawFrame {
                    data: &data[..needed - 1],
                    ..frame
                };
                let e = decode(&short, YuvMatrix::Bt601).unwrap_err();
                assert!(e.to_string().contains(&format!("needs {needed}")), "{e}");
            }
        }
        // 4:2:2 has a chroma row for every row: an odd height is fine (a 6 × 3 NV16 frame
        // decodes as the YUYV frame of its samples).
        let nv16 = PixelFormat::PlanarYuv(PlanarYuv::Nv16);
        let (y3, c3) = (
            &luma[..w * 3],
            (0..w * 3).map(|i| 100 + i as u8).collect::<Vec<u8>>(),
        );
        let data = [y3, &c3[..]].concat();
        let yuyv3: Vec<u8> = (0..w * 3)
            .step_by(2)
            .flat_map(|i| [y3[i], c3[i], y3[i + 1], c3[i + 1]])
            .collect();
        let got = decode(&raw(&data, nv16, w32, 3), YuvMatrix::Bt601).unwrap();
        let want = decode(
            &raw(&yuyv3, PixelFormat::PackedYuv(PackedYuv::Yuyv), w32, 3),
            YuvMatrix::Bt601,
        )
        .unwrap();
        assert_eq!(bits(&got), bits(&want), "NV16 of odd height");
        // Black, white and 100% red (BT.601: Y 81, Cb 90, Cr 240) in NV12, 2 × 2 each.
        for (y, cb, cr, rgb) in [
            (16, 128, 128, [0.0; 3]),
            (235, 128, 128, [1.0; 3]),
            (81, 90, 240, [1.0, 0.0, 0.0]),
        ] {
            let data = [y, y, y, y, cb, cr];
            let format = PixelFormat::PlanarYuv(PlanarYuv::Nv12);
            let img = decode(&raw(&data, format, 2, 2), YuvMatrix::Bt601).unwrap();
            for p in &img.pixels {
                assert!(close(*p, rgb, 0.006), "{p:?} for {rgb:?}");
            }
        }
        // 4:4:4 gives every pixel its own chroma: red, blue, white on one row of 3 (an odd
        // width and height are fine), in NV24 and NV42, each as its own 2 × 2 NV12 frame.
        let samples = [(81u8, 90u8, 240u8), (41, 240, 110), (235, 128, 128)];
        let one_colour = |&(y, cb, cr): &(u8, u8, u8)| {
            let format = PixelFormat::PlanarYuv(PlanarYuv::Nv12);
            decode(&raw(&[y, y, y, y, cb, cr], format, 2, 2), YuvMatrix::Bt601)
                .unwrap()
                .pixels[0]
        };
        let want: Vec<u32> = samples
            .iter()
            .flat_map(|s| one_colour(s).map(f32::to_bits))
            .collect();
        for (layout, cb_first) in [(PlanarYuv::Nv24, true), (PlanarYuv::Nv42, false)] {
            let mut data: Vec<u8> = samples.iter().map(|s| s.0).collect();
            for &(_, cb, cr) in &samples {
                data.extend(if cb_first { [cb, cr] } else { [cr, cb] });
            }
            let format = PixelFormat::PlanarYuv(layout);
            assert_eq!(format.buffer_len(3, 1, 0), Some(data.len()));
            let got = decode(&raw(&data, format, 3, 1), YuvMatrix::Bt601).unwrap();
            assert_eq!(bits(&got), want, "{format}");
        }
        // Odd sizes and an odd stride of the three-plane layouts are errors.
        let data = [0u8; 64];
        let nv12 = PixelFormat::PlanarYuv(PlanarYuv::Nv12);
        let e = decode(&raw(&data, nv12, 4, 3), YuvMatrix::Auto).unwrap_err();
        assert!(e.to_string().contains("height must be even"), "{e}");
        let e = decode(&raw(&data, nv12, 3, 4), YuvMatrix::Auto).unwrap_err();
        assert!(e.to_string().contains("width must be even"), "{e}");
        let frame = RawFrame {
            stride: 5,
            ..raw(&data, PixelFormat::PlanarYuv(PlanarYuv::Yu12), 4, 4)
        };
        let e = decode(&frame, YuvMatrix::Auto).unwrap_err();
        assert!(e.to_string().contains("stride 5 must be even"), "{e}");
        let frame = RawFrame {
            stride: usize::MAX / 2,
            ..raw(&data, nv12, 4, 4)
        };
        let e = decode(&frame, YuvMatrix::Auto).unwrap_err();
        assert!(e.to_string().contains("too large"), "{e}");
    }

    #[test]
    fn yuyv_known_values_bt601_bt709_and_bt2020() {
        // Black, white, and 100% red of each standard: Y = 16 + 219·Kr, Cb = 128 − 112·Kr/(1 − Kb),
        // Cr = 240 (BT.601: 81, 90, 240; BT.709: 63, 102, 240).
        let data = [16, 128, 235, 128];
        let img = decode(
            &raw(&data, PixelFormat::PackedYuv(PackedYuv::Yuyv), 2, 1),
            YuvMatrix::Bt601,
        )
        .unwrap();
        assert!(close(img.pixels[0], [0.0; 3], 1e-6));
        assert!(close(img.pixels[1], [1.0; 3], 1e-6));
        let img = decode(
            &raw(
                &[81, 90, 81, 240],
                PixelFormat::PackedYuv(PackedYuv::Yuyv),
                2,
                1,
            ),
            YuvMatrix::Bt601,
        )
        .unwrap();
        assert!(
            close(img.pixels[0], [1.0, 0.0, 0.0], 0.006),
            "{:?}",
            img.pixels[0]
        );
        let img = decode(
            &raw(
                &[63, 102, 63, 240],
                PixelFormat::PackedYuv(PackedYuv::Yuyv),
                2,
                1,
            ),
            YuvMatrix::Bt709,
        )
        .unwrap();
        assert!(
            close(img.pixels[0], [1.0, 0.0, 0.0], 0.006),
            "{:?}",
            img.pixels[0]
        );
        // BT.2020's 100% red: Y = 16 + 219·0.2627 = 73.5, Cb = 128 − 112·0.2627/0.9407 = 96.7;
        // BT.709's matrix takes it for a magenta-tinted red.
        let red2020 = raw(
            &[74, 97, 74, 240],
            PixelFormat::PackedYuv(PackedYuv::Yuyv),
            2,
            1,
        );
        let img = decode(&red2020, YuvMatrix::Bt2020).unwrap();
        assert!(
            close(img.pixels[0], [1.0, 0.0, 0.0], 0.006),
            "{:?}",
            img.pixels[0]
        );
        let wrong = decode(&red2020, YuvMatrix::Bt709).unwrap();
        assert!(!close(wrong.pixels[0], [1.0, 0.0, 0.0], 0.02), "{wrong:?}");
        // 75% yellow (R = G = 0.75, B = 0) encoded with the BT.709 forward equations
        let (kr, kb) = (0.2126f32, 0.0722f32);
        let (r, g, b) = (0.75f32, 0.75f32, 0.0f32);
        let y = kr * r + (1.0 - kr - kb) * g + kb * b;
        let cb = (b - y) / (2.0 * (1.0 - kb));
        let cr = (r - y) / (2.0 * (1.0 - kr));
        let code = |v: f32| v.round() as u8;
        let quad = [
            code(16.0 + 219.0 * y),
            code(128.0 + 224.0 * cb),
            0,
            code(128.0 + 224.0 * cr),
        ];
        let img = decode(
            &raw(&quad, PixelFormat::PackedYuv(PackedYuv::Yuyv), 2, 1),
            YuvMatrix::Bt709,
        )
        .unwrap();
        assert!(
            close(img.pixels[0], [r, g, b], 0.008),
            "{:?}",
            img.pixels[0]
        );
        // the same code read with the wrong matrix is visibly off
        let wrong = decode(
            &raw(&quad, PixelFormat::PackedYuv(PackedYuv::Yuyv), 2, 1),
            YuvMatrix::Bt601,
        )
        .unwrap();
        assert!(
            !close(wrong.pixels[0], [r, g, b], 0.02),
            "{:?}",
            wrong.pixels[0]
        );
        assert_eq!(YuvMatrix::Auto.resolve(1280, 960), YuvMatrix::Bt709);
        assert_eq!(YuvMatrix::Auto.resolve(640, 480), YuvMatrix::Bt601);
    }

    #[test]
    fn rgb24_bgr24_grey_and_stride() {
        let rgb = [10, 20, 30, 40, 50, 60];
        let a = decode(&raw(&rgb, PixelFormat::Rgb24, 2, 1), YuvMatrix::Auto).unwrap();
        assert_eq!(a.pixels[1], [40.0 / 255.0, 50.0 / 255.0, 60.0 / 255.0]);
        let b = decode(&raw(&rgb, PixelFormat::Bgr24, 2, 1), YuvMatrix::Auto).unwrap();
        assert_eq!(b.pixels[0], [30.0 / 255.0, 20.0 / 255.0, 10.0 / 255.0]);
        // GREY with a padded stride of 4 bytes for a 2-pixel row
        let grey = [0, 255, 9, 9, 51, 102];
        let mut r = raw(&grey, PixelFormat::Grey { bits: 8 }, 2, 2);
        r.stride = 4;
        let g = decode(&r, YuvMatrix::Auto).unwrap();
        let want = [[0.0; 3], [1.0; 3], [0.2; 3], [0.4; 3]];
        assert!(
            g.pixels.iter().zip(want).all(|(p, w)| close(*p, w, 1e-6)),
            "{g:?}"
        );
    }

    #[test]
    fn y10_y12_y16_little_endian() {
        for (bits, code) in [(10u8, 1023u16), (12, 2048), (16, 0xBEEF)] {
            let f = PixelFormat::Grey { bits };
            let b = code.to_le_bytes();
            let img = decode(&raw(&[b[0], b[1], 0, 0], f, 2, 1), YuvMatrix::Auto).unwrap();
            let want = f32::from(code) / f.code_max();
            assert!((img.pixels[0][0] - want).abs() < 1e-7, "Y{bits}");
            assert_eq!(img.pixels[1], [0.0; 3]);
        }
        // an out-of-range 10-bit value is clamped to the largest code
        let img = decode(
            &raw(&[0xFF, 0xFF], PixelFormat::Grey { bits: 10 }, 1, 1),
            YuvMatrix::Auto,
        )
        .unwrap();
        assert_eq!(img.pixels[0], [1.0; 3]);
    }

    /// Mosaics a smooth RGB function with a pattern and checks the demosaic.
    fn mosaic_of(
        f: impl Fn(usize, usize) -> [f32; 3],
        w: usize,
        h: usize,
        pattern: BayerPattern,
        bits: u8,
    ) -> Vec<u8> {
        let max = ((1u32 << bits) - 1) as f32;
        let mut out = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let v = (f(x, y)[pattern.channel(x, y)] * max).round() as u16;
                if bits > 8 {
                    out.extend_from_slice(&v.to_le_bytes());
                } else {
                    out.push(v as u8);
                }
            }
        }
        out
    }

    #[test]
    fn bayer_demosaic_every_pattern_and_depth() {
        let (w, h) = (8usize, 6usize);
        for f in PixelFormat::all() {
            let PixelFormat::Bayer { pattern, bits } = f else {
                continue;
            };
            let max = f.code_max();
            // a constant colour is reproduced everywhere, borders included
            let flat = |_: usize, _: usize| [0.8f32, 0.5, 0.25];
            let data = mosaic_of(flat, w, h, pattern, bits);
            let img = decode(&raw(&data, f, w as u32, h as u32), YuvMatrix::Auto).unwrap();
            let q = |v: f32| (v * max).round() / max;
            for p in &img.pixels {
                assert!(close(*p, [q(0.8), q(0.5), q(0.25)], 1e-6), "{f} {p:?}");
            }
            // a linear ramp (in x and y, different per channel) is exact away from the border
            let ramp = |x: usize, y: usize| {
                let (x, y) = (x as f32, y as f32);
                [0.05 * x + 0.02 * y, 0.1 + 0.03 * x, 0.5 - 0.04 * y]
            };
            let data = mosaic_of(ramp, w, h, pattern, 16);
            let f16 = PixelFormat::Bayer { pattern, bits: 16 };
            let img = decode(&raw(&data, f16, w as u32, h as u32), YuvMatrix::Auto).unwrap();
            for y in 1..h - 1 {
                for x in 1..w - 1 {
                    let p = img.pixels[y * w + x];
                    assert!(close(p, ramp(x, y), 2e-4), "{pattern:?} ({x},{y}) {p:?}");
                }
            }
        }
    }

    /// Every pixel through [`BayerRows::pixel`], the mirrored-index stencil (the demosaic as it
    /// was before the row kernels), row by row. The kernels must give the same bits.
    fn demosaic_per_pixel(
        mosaic: &[f32],
        w: usize,
        h: usize,
        pattern: BayerPattern,
    ) -> Vec<[f32; 3]> {
        let row = |y: usize| &mosaic[y * w..][..w];
        (0..h)
            .flat_map(|y| {
                let rows = BayerRows {
                    up: row(mirror(y as isize - 1, h)),
                    row: row(y),
                    down: row(mirror(y as isize + 1, h)),
                };
                (0..w).map(move |x| rows.pixel(pattern, x, y))
            })
            .collect()
    }

    /// The bit patterns of an image's samples, to compare images bit for bit.
    fn sample_bits(image: &[[f32; 3]]) -> Vec<[u32; 3]> {
        image.iter().map(|p| p.map(f32::to_bits)).collect()
    }

    /// The row kernels (interior pixels in pairs of fixed colours, borders mirrored) give the
    /// per-pixel stencil's bits for every pattern, on small and odd sizes too, alone and with
    /// helper threads. It fails if a kernel's colours, parity or order of additions is wrong.
    #[test]
    fn demosaic_row_kernels_equal_the_per_pixel_stencil_bit_for_bit() {
        let pool = crate::parallel::helper_pool(3, "test-demosaic").unwrap();
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        let sizes = [
            (1, 1),
            (2, 1),
            (1, 3),
            (2, 2),
            (3, 2),
            (4, 3),
            (5, 5),
            (8, 6),
            (67, 41),
        ];
        for (w, h) in sizes {
            let mosaic: Vec<f32> = (0..w * h).map(|_| next()).collect();
            for pattern in [
                BayerPattern::Rggb,
                BayerPattern::Bggr,
                BayerPattern::Grbg,
                BayerPattern::Gbrg,
            ] {
                let want = demosaic_per_pixel(&mosaic, w, h, pattern);
                for helpers in [None, pool.as_ref()] {
                    let mut got = vec![[f32::NAN; 3]; w * h];
                    demosaic_bilinear_on(&mosaic, w, h, pattern, &mut got, helpers);
                    assert_eq!(sample_bits(&got), sample_bits(&want), "{w}x{h} {pattern:?}");
                }
            }
        }
    }

    /// Decoding raw Bayer data (8 and 12 bits, a padded stride, codes above the largest one,
    /// several bands of rows) gives the per-pixel stencil's bits on the normalised codes, alone
    /// and with helper threads: the bands' own code buffers change nothing.
    #[test]
    fn bayer_decoding_equals_the_per_pixel_stencil_bit_for_bit() {
        let pool = crate::parallel::helper_pool(2, "test-bayer").unwrap();
        let (w, h, stride) = (38usize, 2 * ROWS_PER_TASK + 7, 2 * 38 + 6);
        for (bits, pattern) in [(12u8, BayerPattern::Grbg), (8, BayerPattern::Bggr)] {
            let format = PixelFormat::Bayer { pattern, bits };
            let bytes = format.bytes_per_pixel();
            let mut data = vec![0u8; stride * h];
            let mut mosaic = vec![0.0f32; w * h];
            for y in 0..h {
                for x in 0..w {
                    // Every code up to 0xFFFF, past the 12-bit maximum (clamped).
                    let code = ((x * 7919 + y * 104_729) % 65_536) as u16;
                    let at = y * stride + x * bytes;
                    // As the decoder normalises: times the reciprocal of the largest code.
                    let inv = 1.0 / format.code_max();
                    mosaic[y * w + x] = if bytes == 1 {
                        data[at] = code as u8;
                        f32::from(code as u8) * inv
                    } else {
                        data[at..at + 2].copy_from_slice(&code.to_le_bytes());
                        f32::from(code).min(format.code_max()) * inv
                    };
                }
            }
            let mut frame = raw(&data, format, w as u32, h as u32);
            frame.stride = stride;
            let want = sample_bits(&demosaic_per_pixel(&mosaic, w, h, pattern));
            for helpers in [None, pool.as_ref()] {
                let mut img = CodeImage {
                    width: 0,
                    height: 0,
                    pixels: Vec::new(),
                };
                decode_into_on(&frame, YuvMatrix::Auto, &mut img, helpers).unwrap();
                let got = sample_bits(&img.pixels);
                let first_difference = got.iter().zip(&want).position(|(a, b)| a != b);
                assert_eq!(got.len(), want.len(), "{format}");
                assert_eq!(first_difference, None, "{format}");
            }
        }
    }

    #[test]
    fn bayer_pattern_phase() {
        // RGGB: a single red sample at (0,0) of an otherwise black mosaic
        let mut data = vec![0u8; 16];
        data[0] = 255;
        let f = PixelFormat::Bayer {
            pattern: BayerPattern::Rggb,
            bits: 8,
        };
        let img = decode(&raw(&data, f, 4, 4), YuvMatrix::Auto).unwrap();
        assert_eq!(img.pixels[0], [1.0, 0.0, 0.0]);
        // its right neighbour (green site) sees red from the left and, mirrored, the right
        // red site x = 2 (0): (1 + 0)/2
        assert!(
            close(img.pixels[1], [0.5, 0.0, 0.0], 1e-6),
            "{:?}",
            img.pixels[1]
        );
        // the blue site (1,1) averages four red diagonals: (0,0) only is lit
        assert!(
            close(img.pixels[5], [0.25, 0.0, 0.0], 1e-6),
            "{:?}",
            img.pixels[5]
        );
    }

    #[test]
    fn mjpeg_decodes_to_the_encoded_colours() {
        let (w, h) = (16u16, 8u16);
        let mut rgb = Vec::new();
        for y in 0..h {
            for x in 0..w {
                rgb.extend_from_slice(&[(x * 16) as u8, 128, (y * 32) as u8]);
            }
        }
        let mut jpeg = Vec::new();
        jpeg_encoder::Encoder::new(&mut jpeg, 100)
            .encode(&rgb, w, h, jpeg_encoder::ColorType::Rgb)
            .unwrap();
        let img = decode(
            &raw(&jpeg, PixelFormat::Mjpeg, w.into(), h.into()),
            YuvMatrix::Auto,
        )
        .unwrap();
        let mut worst = 0.0f32;
        for (p, want) in img.pixels.iter().zip(rgb.chunks_exact(3)) {
            for c in 0..3 {
                worst = worst.max((p[c] - f32::from(want[c]) / 255.0).abs());
            }
        }
        assert!(worst < 6.0 / 255.0, "worst difference {worst}");
        // MJPEG as many UVC cameras send it: the DHT segments left out (standard tables)
        let mut stripped = vec![0xFF, 0xD8];
        let mut pos = 2;
        let mut removed = 0;
        while pos + 4 <= jpeg.len() && jpeg[pos + 1] != 0xDA {
            let len = usize::from(u16::from_be_bytes([jpeg[pos + 2], jpeg[pos + 3]]));
            if jpeg[pos + 1] == 0xC4 {
                removed += 1;
            } else {
                stripped.extend_from_slice(&jpeg[pos..pos + 2 + len]);
            }
            pos += 2 + len;
        }
        stripped.extend_from_slice(&jpeg[pos..]);
        assert!(removed > 0 && !has_huffman_tables(&stripped));
        // zune-jpeg alone cannot decode it
        let mut plain = zune_jpeg::JpegDecoder::new(
            zune_jpeg::zune_core::bytestream::ZCursor::new(&stripped[..]),
        );
        assert!(plain.decode().is_err());
        let no_dht = decode(
            &raw(&stripped, PixelFormat::Mjpeg, w.into(), h.into()),
            YuvMatrix::Auto,
        )
        .unwrap();
        assert_eq!(no_dht.pixels, img.pixels);
        // a frame of the wrong size is an error naming both sizes
        let err = decode(&raw(&jpeg, PixelFormat::Mjpeg, 32, 8), YuvMatrix::Auto).unwrap_err();
        assert!(err.to_string().contains("16x8"), "{err}");
    }

    fn pool(threads: usize) -> rayon::ThreadPool {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a thread pool")
    }

    /// Rows can be decoded in parallel: the code values must be the same to the bit on the
    /// calling thread and on a pool, for every format (72×100 frames: several bands of rows).
    #[test]
    fn decoding_does_not_depend_on_the_number_of_threads() {
        let (w, h) = (72u32, 100u32);
        let mut byte = byte_stream(0x2545_f491_4f6c_dd1du64);
        let mut rgb = Vec::new();
        for _ in 0..w * h * 3 {
            rgb.push(byte() / 2 + 64);
        }
        let mut jpeg = Vec::new();
        jpeg_encoder::Encoder::new(&mut jpeg, 90)
            .encode(&rgb, w as u16, h as u16, jpeg_encoder::ColorType::Rgb)
            .unwrap();
        for format in PixelFormat::all() {
            let data: Vec<u8> = if format == PixelFormat::Mjpeg {
                jpeg.clone()
            } else {
                (0..format.buffer_len(w, h, 0).unwrap())
                    .map(|_| byte())
                    .collect()
            };
            let frame = raw(&data, format, w, h);
            let one = decode(&frame, YuvMatrix::Auto).unwrap();
            let mut three = CodeImage {
                width: 0,
                height: 0,
                pixels: Vec::new(),
            };
            decode_into_on(&frame, YuvMatrix::Auto, &mut three, Some(&pool(3))).unwrap();
            assert_eq!(one.pixels.len(), (w * h) as usize, "{format}");
            assert!(
                one.pixels
                    .iter()
                    .flatten()
                    .zip(three.pixels.iter().flatten())
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{format}"
            );
            assert!(one.pixels.iter().flatten().any(|&v| v > 0.0), "{format}");
        }
    }

    #[test]
    fn malformed_buffers_are_errors_not_panics() {
        let formats = PixelFormat::all();
        let garbage: Vec<u8> = (0..200u32).map(|i| (i * 37 % 251) as u8).collect();
        for f in formats {
            for (w, h) in [
                (4u32, 4u32),
                (3, 3),
                (0, 4),
                (1, 1),
                (100, 100),
                (u32::MAX, 2),
            ] {
                for len in [0usize, 1, 7, 31, 32, 200] {
                    let r = raw(&garbage[..len], f, w, h);
                    // must return (Ok or Err), never panic
                    let res = decode(&r, YuvMatrix::Auto);
                    if f != PixelFormat::Mjpeg && len < w as usize * h as usize {
                        assert!(res.is_err(), "{f} {w}x{h} len {len}");
                    }
                }
            }
        }
        let short = decode(
            &raw(&[0; 10], PixelFormat::Grey { bits: 16 }, 4, 4),
            YuvMatrix::Auto,
        )
        .unwrap_err();
        assert!(short.to_string().contains("needs 32"), "{short}");
        let mut r = raw(&[0; 64], PixelFormat::Rgb24, 4, 4);
        r.stride = 5;
        let e = decode(&r, YuvMatrix::Auto).unwrap_err();
        assert!(e.to_string().contains("stride 5"), "{e}");
        r.stride = usize::MAX;
        let e = decode(&r, YuvMatrix::Auto).unwrap_err();
        assert!(e.to_string().contains("too large"), "{e}");
        let e = decode(
            &raw(&[0; 64], PixelFormat::PackedYuv(PackedYuv::Yuyv), 3, 2),
            YuvMatrix::Auto,
        )
        .unwrap_err();
        assert!(e.to_string().contains("even"), "{e}");
        let e = decode(&raw(&garbage, PixelFormat::Mjpeg, 4, 4), YuvMatrix::Auto).unwrap_err();
        assert!(e.to_string().starts_with("MJPEG"), "{e}");
    }

    /// A frame kept as bytes gives the same code values to the bit as decoding it to floats,
    /// for every one-byte-code format, padded rows included, on one thread and on a pool; a
    /// used byte buffer is written over; other formats are refused by name.
    #[test]
    fn byte_frames_give_the_codes_of_the_float_decode() {
        let (w, h) = (70u32, 100u32);
        let mut byte = byte_stream(0x9e37_79b9_7f4a_7c15u64);
        // every seventh pixel grey (R = G = B), so both kinds occur
        let mut rgb = Vec::new();
        for i in 0..w * h {
            let v = byte();
            if i % 7 == 0 {
                rgb.extend_from_slice(&[v; 3]);
            } else {
                rgb.extend_from_slice(&[v, byte(), byte()]);
            }
        }
        let mut jpeg = Vec::new();
        jpeg_encoder::Encoder::new(&mut jpeg, 90)
            .encode(&rgb, w as u16, h as u16, jpeg_encoder::ColorType::Rgb)
            .unwrap();
        // rows padded to a stride of 3·w + 5 bytes, the padding filled with 0xEE
        let padded = |bpp: usize, src: &[u8]| -> Vec<u8> {
            let row = bpp * w as usize;
            src.chunks_exact(row)
                .flat_map(|r| r.iter().copied().chain([0xEE; 5]))
                .collect()
        };
        let grey: Vec<u8> = rgb.iter().step_by(3).copied().collect();
        let rgb_padded = padded(3, &rgb);
        let grey_padded = padded(1, &grey);
        let cases: Vec<(PixelFormat, &[u8], usize)> = vec![
            (PixelFormat::Mjpeg, &jpeg, 0),
            (PixelFormat::Rgb24, &rgb, 0),
            (PixelFormat::Bgr24, &rgb, 0),
            (PixelFormat::Rgb24, &rgb_padded, 3 * w as usize + 5),
            (PixelFormat::Bgr24, &rgb_padded, 3 * w as usize + 5),
            (PixelFormat::Grey { bits: 8 }, &grey, 0),
            (PixelFormat::Grey { bits: 8 }, &grey_padded, w as usize + 5),
        ];
        let helpers = pool(2);
        for (format, data, stride) in cases {
            let frame = RawFrame {
                data,
                format,
                width: w,
                height: h,
                stride,
            };
            let want = decode(&frame, YuvMatrix::Auto).unwrap();
            for threads in [None, Some(&helpers)] {
                // a used buffer of the right size, and one of another size
                for used in [
                    vec![0xAB; data.len().max(3 * (w * h) as usize)],
                    vec![7; 10],
                ] {
                    let mut bytes = ByteImage {
                        bytes: used,
                        ..ByteImage::default()
                    };
                    decode_bytes_into_on(&frame, &mut bytes, threads).unwrap();
                    assert_eq!((bytes.width, bytes.height), (w, h));
                    let channels = match format {
                        PixelFormat::Grey { .. } => 1,
                        _ => 3,
                    };
                    assert_eq!(bytes.channels, channels, "{format}");
                    assert_eq!(bytes.bytes.len(), channels * (w * h) as usize, "{format}");
                    let mut codes = CodeImage {
                        width: 0,
                        height: 0,
                        pixels: vec![[f32::NAN; 3]; 3],
                    };
                    bytes.to_codes_into_on(&mut codes, threads);
                    assert_eq!((codes.width, codes.height), (w, h));
                    assert!(
                        codes
                            .pixels
                            .iter()
                            .flatten()
                            .zip(want.pixels.iter().flatten())
                            .all(|(a, b)| a.to_bits() == b.to_bits()),
                        "{format} stride {stride}"
                    );
                }
            }
        }
        // BGR24 is reordered: its first pixel's bytes come back reversed
        let mut bytes = ByteImage::default();
        let frame = raw(&rgb, PixelFormat::Bgr24, w, h);
        decode_bytes_into_on(&frame, &mut bytes, None).unwrap();
        assert_eq!(bytes.bytes[..3], [rgb[2], rgb[1], rgb[0]]);
        // formats whose codes are not bytes, and bad buffers, are errors
        for format in PixelFormat::all()
            .into_iter()
            .filter(|f| !f.has_byte_codes())
        {
            let data = vec![0u8; 2 * (w * h) as usize * format.bytes_per_pixel().max(1)];
            let e = decode_bytes_into_on(&raw(&data, format, w, h), &mut bytes, None).unwrap_err();
            assert!(e.to_string().contains("not one byte"), "{format}: {e}");
        }
        let e = decode_bytes_into_on(
            &raw(&rgb[..100], PixelFormat::Rgb24, w, h),
            &mut bytes,
            None,
        )
        .unwrap_err();
        assert!(matches!(e, PixelError::Short { .. }), "{e}");
        let e = decode_bytes_into_on(&raw(&jpeg, PixelFormat::Mjpeg, w, h + 1), &mut bytes, None)
            .unwrap_err();
        assert!(e.to_string().contains("negotiated frame size"), "{e}");
    }

    /// zune-jpeg writes every byte of its output even for a stream cut short, so a reused
    /// buffer needs no clearing: a truncated frame decoded into a buffer full of another
    /// frame's bytes equals the same frame decoded into a fresh one.
    #[test]
    fn truncated_mjpeg_into_a_used_buffer_equals_a_fresh_decode() {
        let (w, h) = (48u16, 40u16);
        let rgb: Vec<u8> = (0..u32::from(w) * u32::from(h) * 3)
            .map(|i| (i * 37 % 251) as u8)
            .collect();
        let mut jpeg = Vec::new();
        jpeg_encoder::Encoder::new(&mut jpeg, 85)
            .encode(&rgb, w, h, jpeg_encoder::ColorType::Rgb)
            .unwrap();
        let mut decoded_cut = 0;
        for cut in (jpeg.len() / 3..jpeg.len()).step_by(7) {
            let frame = raw(&jpeg[..cut], PixelFormat::Mjpeg, w.into(), h.into());
            let mut fresh = ByteImage::default();
            let fresh_result = decode_bytes_into_on(&frame, &mut fresh, None);
            let mut used = ByteImage {
                bytes: vec![0xAB; 3 * usize::from(w) * usize::from(h)],
                ..ByteImage::default()
            };
            let used_result = decode_bytes_into_on(&frame, &mut used, None);
            assert_eq!(fresh_result.is_ok(), used_result.is_ok(), "cut at {cut}");
            if fresh_result.is_ok() {
                decoded_cut += 1;
                assert!(fresh.bytes == used.bytes, "cut at {cut} of {}", jpeg.len());
            }
        }
        // the test must have decoded truncated streams, not only rejected them
        assert!(decoded_cut > 10, "{decoded_cut} truncated streams decoded");
    }
}
