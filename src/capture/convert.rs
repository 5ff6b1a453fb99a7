//! A camera frame's way from the driver's buffer to radiance, apart from the device: the V4L2
//! source ([`super::v4l2`]) dequeues buffers and reads the exposure; everything after that is
//! here, where it is tested on made-up buffers (no camera exists on the build machines).
//!
//! 1. [`FrameConverter::keep`]: while the driver's buffer is lent, it is checked and kept in
//!    the cheapest form its format allows: one-byte codes (MJPEG once decoded, RGB24, BGR24,
//!    GREY) as bytes, the packed formats (YUYV, Y10/Y12/Y16, Bayer) as a copy of the buffer,
//!    and, when exposure brackets are merged, every format as normalised codes. A buffer that
//!    fails (short, corrupt JPEG) is an error and the frame kept before stays kept.
//! 2. [`FrameConverter::radiance`]: once the frame's exposure time and gain are known, the
//!    kept frame becomes radiance through a [`Linearizer`] that is rebuilt only when they
//!    change (auto exposure): bytes through 256-entry tables, a copied buffer decoded and
//!    linearised in one pass over bands of rows, codes through the tables. The radiance is
//!    written into a buffer the pipeline handed back ([`FrameConverter::recycle`]) when there
//!    is one. Every way gives the radiances of decoding to codes and linearising them, to the
//!    bit (tests in [`super::pixel_format`] and [`super::response`]).
//! 3. [`FrameConverter::codes`]: the kept frame's normalised codes, for merging brackets
//!    ([`super::bracket`]) and for calibrating the response.
//!
//! The conversions run on the calling thread and an optional pool of helpers
//! (src/parallel.rs).

use super::pixel_format::{
    self, ByteImage, CodeImage, PixelError, PixelFormat, RawFrame, YuvMatrix,
};
use super::response::{Linearizer, Radiometry, ResponseModel};

/// How a frame is kept between [`FrameConverter::keep`] and its linearisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kept {
    /// Normalised codes: exposure brackets are merged from these.
    Codes,
    /// Bytes ([`ByteImage`]; MJPEG, RGB24, BGR24, GREY), linearised through byte tables.
    Bytes,
    /// A copy of the driver's buffer (YUYV, 10- to 16-bit grey, Bayer), decoded and
    /// linearised in one pass over bands of rows.
    Raw,
}

/// The negotiated stream: format, size and row stride in bytes (0: packed rows).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StreamFormat {
    pub format: PixelFormat,
    pub width: u32,
    pub height: u32,
    pub stride: usize,
}

impl StreamFormat {
    /// `data` as a raw frame of this stream.
    pub fn raw<'a>(&self, data: &'a [u8]) -> RawFrame<'a> {
        RawFrame {
            data,
            format: self.format,
            width: self.width,
            height: self.height,
            stride: self.stride,
        }
    }
}

/// What turns a code into radiance apart from the exposure: the response model, the Y'CbCr
/// matrix of the Y'CbCr formats, white balance and absolute scale (docs/camera.md).
#[derive(Clone, Debug)]
pub struct Calibration {
    pub response: ResponseModel,
    pub yuv_matrix: YuvMatrix,
    pub white_balance: [f64; 3],
    pub scale: f64,
}

impl Calibration {
    /// This calibration with exposure time `exposure_s` and gain `gain`.
    pub fn radiometry(&self, exposure_s: f64, gain: f64) -> Radiometry {
        Radiometry {
            exposure_s,
            gain,
            white_balance: self.white_balance,
            scale: self.scale,
        }
    }
}

/// Keeps the latest camera frame and converts it to radiance (see the module docs).
pub struct FrameConverter {
    stream: StreamFormat,
    calibration: Calibration,
    kept: Kept,
    /// Whether a frame has been kept (and no failed buffer came after it).
    has_frame: bool,
    codes: CodeImage,
    bytes: ByteImage,
    raw_copy: Vec<u8>,
    /// Tables for the last (exposure, gain) bit patterns.
    linearizer: Option<((u64, u64), Linearizer)>,
    tables_built: u64,
    pool: Option<rayon::ThreadPool>,
    /// A radiance buffer handed back by the pipeline: the next frame is written into it (a
    /// 1280×960 frame's 15 MB, whose zeroing or first touch cost about as much as the linear
    /// conversion itself).
    spare_pixels: Vec<[f32; 3]>,
}

impl FrameConverter {
    /// A converter for `stream`'s frames; `merges_brackets` keeps codes (for
    /// [`super::bracket::merge_brackets`]); `pool`: helper threads (`None`: the calling
    /// thread converts alone).
    pub fn new(
        stream: StreamFormat,
        calibration: Calibration,
        merges_brackets: bool,
        pool: Option<rayon::ThreadPool>,
    ) -> Self {
        let kept = if merges_brackets {
            Kept::Codes
        } else if stream.format.has_byte_codes() {
            Kept::Bytes
        } else {
            Kept::Raw
        };
        Self {
            stream,
            calibration,
            kept,
            has_frame: false,
            codes: CodeImage::default(),
            bytes: ByteImage::default(),
            raw_copy: Vec::new(),
            linearizer: None,
            tables_built: 0,
            pool,
            spare_pixels: Vec::new(),
        }
    }

    /// How frames are kept.
    pub fn kept(&self) -> Kept {
        self.kept
    }

    /// The calibration with exposure time `exposure_s` and gain `gain`.
    pub fn radiometry(&self, exposure_s: f64, gain: f64) -> Radiometry {
        self.calibration.radiometry(exposure_s, gain)
    }

    /// How many times the linearisation tables were built (once per exposure and gain).
    pub fn tables_built(&self) -> u64 {
        self.tables_built
    }

    /// Checks a driver buffer (its bytes in use) and keeps its frame. On an error the buffer
    /// is not kept, and neither is the frame before it (it may be partly overwritten).
    pub fn keep(&mut self, data: &[u8]) -> Result<(), PixelError> {
        let raw = self.stream.raw(data);
        let pool = self.pool.as_ref();
        let kept = match self.kept {
            Kept::Bytes => pixel_format::decode_bytes_into_on(&raw, &mut self.bytes, pool),
            // Checked now, converted once the exposure is known: a packed buffer that passes
            // the check decodes.
            Kept::Raw => pixel_format::check(&raw).map(|()| {
                self.raw_copy.clear();
                self.raw_copy.extend_from_slice(data);
            }),
            Kept::Codes => pixel_format::decode_into_on(
                &raw,
                self.calibration.yuv_matrix,
                &mut self.codes,
                pool,
            ),
        };
        self.has_frame = kept.is_ok();
        kept
    }

    fn no_frame(&self) -> PixelError {
        PixelError::Geometry {
            format: self.stream.format,
            width: self.stream.width,
            height: self.stream.height,
            message: "no frame has been kept".into(),
        }
    }

    /// The kept frame's radiance, with exposure time `exposure_s` (seconds) and linear gain
    /// `gain`; every pixel is written, into the recycled buffer if there is one.
    pub fn radiance(&mut self, exposure_s: f64, gain: f64) -> Result<Vec<[f32; 3]>, PixelError> {
        if !self.has_frame {
            return Err(self.no_frame());
        }
        let key = (exposure_s.to_bits(), gain.to_bits());
        if self.linearizer.as_ref().is_some_and(|(k, _)| *k != key) {
            self.linearizer = None;
        }
        let (_, lin) = self.linearizer.get_or_insert_with(|| {
            self.tables_built += 1;
            let radiometry = self.calibration.radiometry(exposure_s, gain);
            let code_max = self.stream.format.code_max();
            (
                key,
                Linearizer::new(&self.calibration.response, code_max, &radiometry),
            )
        });
        let mut pixels = std::mem::take(&mut self.spare_pixels);
        let pool = self.pool.as_ref();
        let converted = match self.kept {
            Kept::Bytes => {
                lin.linearize_bytes_into_on(&self.bytes, &mut pixels, pool);
                Ok(())
            }
            Kept::Raw => lin.decode_linearize_into_on(
                &self.stream.raw(&self.raw_copy),
                self.calibration.yuv_matrix,
                &mut pixels,
                pool,
            ),
            Kept::Codes => {
                lin.linearize_into_on(&self.codes, &mut pixels, pool);
                Ok(())
            }
        };
        match converted {
            Ok(()) => Ok(pixels),
            Err(e) => {
                // The buffer stays for the next frame.
                self.spare_pixels = pixels;
                Err(e)
            }
        }
    }

    /// The kept frame's normalised codes.
    pub fn codes(&mut self) -> Result<&CodeImage, PixelError> {
        if !self.has_frame {
            return Err(self.no_frame());
        }
        let pool = self.pool.as_ref();
        match self.kept {
            Kept::Codes => {}
            Kept::Bytes => self.bytes.to_codes_into_on(&mut self.codes, pool),
            Kept::Raw => {
                let raw = self.stream.raw(&self.raw_copy);
                pixel_format::decode_into_on(
                    &raw,
                    self.calibration.yuv_matrix,
                    &mut self.codes,
                    pool,
                )?;
            }
        }
        Ok(&self.codes)
    }

    /// Takes back a radiance buffer the pipeline is done with; only one that holds a whole
    /// frame is kept (a smaller one saves nothing).
    pub fn recycle(&mut self, pixels: Vec<[f32; 3]>) {
        if pixels.capacity() >= self.stream.width as usize * self.stream.height as usize {
            self.spare_pixels = pixels;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::pixel_format::{byte_stream, decode, BayerPattern, PackedYuv};

    const W: u32 = 40;
    const H: u32 = 70;

    fn calibration() -> Calibration {
        Calibration {
            response: ResponseModel::Srgb,
            yuv_matrix: YuvMatrix::Bt709,
            white_balance: [1.2, 1.0, 0.9],
            scale: 2.5,
        }
    }

    /// A frame of `format` (rows padded by 4 bytes) whose bytes come from `seed`.
    fn frame(format: PixelFormat, seed: u64) -> (StreamFormat, Vec<u8>) {
        let mut byte = byte_stream(seed);
        if format == PixelFormat::Mjpeg {
            let rgb: Vec<u8> = (0..3 * W * H).map(|_| byte()).collect();
            let mut jpeg = Vec::new();
            jpeg_encoder::Encoder::new(&mut jpeg, 90)
                .encode(&rgb, W as u16, H as u16, jpeg_encoder::ColorType::Rgb)
                .unwrap();
            let stream = StreamFormat {
                format,
                width: W,
                height: H,
                stride: 0,
            };
            return (stream, jpeg);
        }
        let stride = format.row_bytes(W) + 4;
        let len = format.buffer_len(W, H, stride).expect("a valid test frame");
        let data = (0..len).map(|_| byte()).collect();
        let stream = StreamFormat {
            format,
            width: W,
            height: H,
            stride,
        };
        (stream, data)
    }

    fn bits(pixels: &[[f32; 3]]) -> Vec<u32> {
        pixels.iter().flatten().map(|v| v.to_bits()).collect()
    }

    #[test]
    fn each_format_is_kept_in_its_cheapest_form() {
        let rg12 = PixelFormat::Bayer {
            pattern: BayerPattern::Rggb,
            bits: 12,
        };
        for (format, kept) in [
            (PixelFormat::Mjpeg, Kept::Bytes),
            (PixelFormat::Rgb24, Kept::Bytes),
            (PixelFormat::Bgr24, Kept::Bytes),
            (PixelFormat::Grey { bits: 8 }, Kept::Bytes),
            (PixelFormat::Grey { bits: 16 }, Kept::Raw),
            (PixelFormat::PackedYuv(PackedYuv::Yuyv), Kept::Raw),
            (rg12, Kept::Raw),
        ] {
            let (stream, _) = frame(format, 1);
            let converter = FrameConverter::new(stream, calibration(), false, None);
            assert_eq!(converter.kept(), kept, "{format}");
            let converter = FrameConverter::new(stream, calibration(), true, None);
            assert_eq!(converter.kept(), Kept::Codes, "{format}");
        }
    }

    /// Every format, kept either way, gives the radiance and the codes of decoding the buffer
    /// and linearising its codes, to the bit, on one thread and with helpers; the frame
    /// converted is the last one kept.
    #[test]
    fn radiance_and_codes_equal_decoding_then_linearising() {
        let pool = || {
            rayon::ThreadPoolBuilder::new()
                .num_threads(2)
                .build()
                .expect("a thread pool")
        };
        for format in PixelFormat::all() {
            let (stream, first) = frame(format, 3);
            let (_, data) = frame(format, 4);
            let codes = decode(&stream.raw(&data), YuvMatrix::Bt709).unwrap();
            for merges_brackets in [false, true] {
                for helpers in [None, Some(pool())] {
                    let mut converter =
                        FrameConverter::new(stream, calibration(), merges_brackets, helpers);
                    converter.keep(&first).unwrap();
                    converter.keep(&data).unwrap();
                    for (t, g) in [(0.01, 1.0), (0.004, 2.0)] {
                        let lin = Linearizer::new(
                            &ResponseModel::Srgb,
                            format.code_max(),
                            &converter.radiometry(t, g),
                        );
                        let want = lin.linearize(&codes);
                        let got = converter.radiance(t, g).unwrap();
                        assert_eq!(bits(&got), bits(&want), "{format} {merges_brackets}");
                    }
                    let got = converter.codes().unwrap();
                    assert_eq!(got, &codes, "{format} {merges_brackets}");
                }
            }
        }
    }

    #[test]
    fn tables_are_built_once_per_exposure_and_gain() {
        let (stream, data) = frame(PixelFormat::PackedYuv(PackedYuv::Yuyv), 5);
        let mut converter = FrameConverter::new(stream, calibration(), false, None);
        converter.keep(&data).unwrap();
        let mut built = Vec::new();
        for (t, g) in [
            (0.01, 1.0),
            (0.01, 1.0),
            (0.02, 1.0),
            (0.02, 2.0),
            (0.02, 2.0),
            (0.01, 1.0),
        ] {
            converter.radiance(t, g).unwrap();
            built.push(converter.tables_built());
        }
        assert_eq!(built, [1, 1, 2, 3, 3, 4]);
    }

    /// A buffer the pipeline hands back receives the next frame; one too small for a frame is
    /// not kept.
    #[test]
    fn recycled_buffers_receive_the_next_frame() {
        for format in [PixelFormat::Mjpeg, PixelFormat::PackedYuv(PackedYuv::Yuyv)] {
            let (stream, data) = frame(format, 6);
            let mut converter = FrameConverter::new(stream, calibration(), false, None);
            converter.keep(&data).unwrap();
            let want = bits(&converter.radiance(0.01, 1.0).unwrap());
            let spare = vec![[f32::NAN; 3]; (W * H) as usize];
            let at = spare.as_ptr();
            converter.recycle(spare);
            // Had the converter dropped the buffer, this allocation would take its memory.
            let decoy = vec![[0.0f32; 3]; (W * H) as usize];
            let got = converter.radiance(0.01, 1.0).unwrap();
            assert_ne!(decoy.as_ptr(), at);
            assert_eq!(got.as_ptr(), at, "{format}");
            assert_eq!(bits(&got), want, "{format}");
            converter.recycle(Vec::with_capacity(10));
            assert!(converter.spare_pixels.is_empty(), "{format}");
        }
    }

    /// A buffer that fails its check is an error, and nothing is converted until a good one
    /// is kept; before the first frame there is nothing to convert either.
    #[test]
    fn a_bad_buffer_is_an_error_and_leaves_no_frame() {
        for format in [
            PixelFormat::Mjpeg,
            PixelFormat::PackedYuv(PackedYuv::Yuyv),
            PixelFormat::Rgb24,
        ] {
            let (stream, data) = frame(format, 7);
            for merges_brackets in [false, true] {
                let mut converter =
                    FrameConverter::new(stream, calibration(), merges_brackets, None);
                let none = converter.radiance(0.01, 1.0).unwrap_err();
                assert!(none.to_string().contains("no frame"), "{none}");
                converter.keep(&data).unwrap();
                assert!(converter.radiance(0.01, 1.0).is_ok());
                // a JPEG cut inside its header, a packed buffer one row short
                let cut = if format == PixelFormat::Mjpeg {
                    20
                } else {
                    data.len() - stream.stride
                };
                assert!(converter.keep(&data[..cut]).is_err(), "{format}");
                assert!(converter.radiance(0.01, 1.0).is_err(), "{format}");
                assert!(converter.codes().is_err(), "{format}");
                converter.keep(&data).unwrap();
                assert!(converter.codes().is_ok(), "{format}");
            }
        }
    }
}
