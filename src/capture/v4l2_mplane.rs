//! Formats of V4L2's multi-planar API (`V4L2_BUF_TYPE_VIDEO_CAPTURE_MPLANE`), the one that SoC
//! camera pipelines use (Rockchip's ISP, NXP i.MX, Allwinner, the Raspberry Pi ISP and many
//! other MIPI CSI-2 receivers): a frame is one buffer made of up to eight planes, each mapped on
//! its own. The `v4l` crate knows single-planar formats only, so this module makes the calls
//! itself, with the crate's ioctl wrapper and the kernel's structures (`v4l::v4l_sys`):
//!
//! 1. [`enum_formats`]: `VIDIOC_ENUM_FMT` for the node's buffer type (it and
//!    [`set_frame_rate`] serve single-planar nodes too). Formats whose planes
//!    are separate buffers have their own codes (`NM12` is NV12 with the luma and the chroma in
//!    two planes, `YM12` YUV 4:2:0 in three); [`pixel_format`] names each by the pixel format of
//!    its one-buffer twin, so `formats = ["NV12"]` in the config takes `NM12` too;
//! 2. [`set_format`]: `VIDIOC_G_FMT` then `VIDIOC_S_FMT` with `v4l2_pix_format_mplane`; the
//!    driver's answer gives the planes' count and their bytes per line;
//!    [`set_frame_rate`]: `VIDIOC_S_PARM`;
//! 3. streaming: [`super::v4l2_stream::MmapStream`] (both APIs), which hands on a frame in one
//!    plane where the driver wrote it and copies a frame in several planes with
//!    [`gather_planes`] into the one-buffer layout of its twin with rows packed (stride = row
//!    bytes), so everything after the buffer is the same code as for a single-planar camera.

use super::pixel_format::PixelFormat;
use super::v4l2::CaptureApi;
use super::v4l2_stream::{ioctl, kernel_string, named, named_on, CAPTURE_MPLANE, MAX_PLANES};
use std::io;
use v4l::device::Handle;
use v4l::v4l2::vidioc;
use v4l::v4l_sys::{v4l2_fmtdesc, v4l2_format, v4l2_streamparm};
/// `V4L2_CAP_TIMEPERFRAME`: the driver takes a frame interval.
const CAP_TIMEPERFRAME: u32 = 0x1000;

/// Formats whose planes are separate buffers, with the code of their one-buffer twin.
pub const SEPARATE_PLANE_FOURCCS: [([u8; 4], [u8; 4]); 7] = [
    (*b"NM12", *b"NV12"),
    (*b"NM21", *b"NV21"),
    (*b"YM12", *b"YU12"),
    (*b"YM21", *b"YV12"),
    (*b"NM16", *b"NV16"),
    (*b"NM61", *b"NV61"),
    (*b"YM16", *b"422P"),
];

/// The pixel format that `code` names on a multi-planar node: a separate-plane code as its
/// one-buffer twin (`NM12` → NV12), every other code as on a single-planar node.
pub fn pixel_format(code: [u8; 4]) -> Option<PixelFormat> {
    let twin = SEPARATE_PLANE_FOURCCS
        .iter()
        .find(|(separate, _)| *separate == code)
        .map_or(code, |(_, twin)| *twin);
    PixelFormat::from_fourcc(twin)
}

/// A format the driver set on a multi-planar node.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MplaneFormat {
    pub fourcc: [u8; 4],
    pub width: u32,
    pub height: u32,
    /// `V4L2_COLORSPACE_*`.
    pub colorspace: u32,
    /// Bytes per line of each plane.
    pub strides: Vec<usize>,
}

impl MplaneFormat {
    /// The bytes between rows of the frame as [`super::v4l2_stream::MmapStream::next_frame`]
    /// hands it on: the driver's for a one-plane format, packed rows (the row's bytes) for a
    /// gathered one.
    pub fn stride(&self, format: PixelFormat) -> usize {
        match self.strides.as_slice() {
            [one] => *one,
            _ => format.row_bytes(self.width),
        }
    }
}

/// The formats a node offers through `api`: each fourcc with the driver's description, read
/// lossily (the `v4l` crate's enumeration unwraps it into UTF-8, a panic on a description cut
/// in the middle of a character).
pub fn enum_formats(handle: &Handle, api: CaptureApi) -> io::Result<Vec<([u8; 4], String)>> {
    let mut formats = Vec::new();
    // A driver lists a few dozen at most; the bound keeps a broken one from looping forever.
    for index in 0..256 {
        // SAFETY: all-zero is a valid v4l2_fmtdesc (plain integers and bytes).
        let mut desc: v4l2_fmtdesc = unsafe { std::mem::zeroed() };
        desc.index = index;
        desc.type_ = api.buffer_type();
        // SAFETY: VIDIOC_ENUM_FMT reads and writes a v4l2_fmtdesc.
        match unsafe { ioctl(handle, vidioc::VIDIOC_ENUM_FMT, &mut desc) } {
            Ok(()) => {}
            Err(e) if e.raw_os_error() == Some(libc::EINVAL) => break,
            Err(e) => return Err(named_on(api, "VIDIOC_ENUM_FMT", e)),
        }
        formats.push((
            desc.pixelformat.to_le_bytes(),
            kernel_string(&desc.description),
        ));
    }
    Ok(formats)
}

/// Asks for `fourcc` at `width`×`height` and returns what the driver set.
pub fn set_format(
    handle: &Handle,
    fourcc: [u8; 4],
    width: u32,
    height: u32,
) -> io::Result<MplaneFormat> {
    // SAFETY: all-zero is a valid v4l2_format (integers, and a union of such structures).
    let mut format: v4l2_format = unsafe { std::mem::zeroed() };
    format.type_ = CAPTURE_MPLANE;
    // SAFETY: VIDIOC_G_FMT / VIDIOC_S_FMT read and write a v4l2_format; for this buffer type
    // the union holds `pix_mp`.
    unsafe {
        ioctl(handle, vidioc::VIDIOC_G_FMT, &mut format)
            .map_err(|e| named("VIDIOC_G_FMT (multi-planar)", e))?;
        format.fmt.pix_mp.width = width;
        format.fmt.pix_mp.height = height;
        format.fmt.pix_mp.pixelformat = u32::from_le_bytes(fourcc);
        // The driver fills in the planes for the new format.
        format.fmt.pix_mp.num_planes = 0;
        format.fmt.pix_mp.plane_fmt = std::mem::zeroed();
        ioctl(handle, vidioc::VIDIOC_S_FMT, &mut format)
            .map_err(|e| named("VIDIOC_S_FMT (multi-planar)", e))?;
        mplane_format(&format.fmt.pix_mp)
    }
}

fn mplane_format(pix: &v4l::v4l_sys::v4l2_pix_format_mplane) -> io::Result<MplaneFormat> {
    let count = usize::from(pix.num_planes);
    if !(1..=MAX_PLANES).contains(&count) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!("VIDIOC_S_FMT (multi-planar): the driver set {count} planes"),
        ));
    }
    Ok(MplaneFormat {
        fourcc: pix.pixelformat.to_le_bytes(),
        width: pix.width,
        height: pix.height,
        colorspace: pix.colorspace,
        strides: pix.plane_fmt[..count]
            .iter()
            .map(|p| p.bytesperline as usize)
            .collect(),
    })
}

/// Asks for `fps` frames a second through `api` (`VIDIOC_S_PARM`); an error where the driver
/// takes no frame interval.
pub fn set_frame_rate(handle: &Handle, api: CaptureApi, fps: f64) -> io::Result<()> {
    // SAFETY: all-zero is a valid v4l2_streamparm.
    let mut parm: v4l2_streamparm = unsafe { std::mem::zeroed() };
    parm.type_ = api.buffer_type();
    // SAFETY: VIDIOC_G_PARM / VIDIOC_S_PARM read and write a v4l2_streamparm; for a capture
    // buffer type the union holds `capture`.
    unsafe {
        ioctl(handle, vidioc::VIDIOC_G_PARM, &mut parm)
            .map_err(|e| named_on(api, "VIDIOC_G_PARM", e))?;
        if parm.parm.capture.capability & CAP_TIMEPERFRAME == 0 {
            let e = io::Error::new(
                io::ErrorKind::Unsupported,
                "the driver sets no frame interval",
            );
            return Err(named_on(api, "VIDIOC_S_PARM", e));
        }
        parm.parm.capture.timeperframe.numerator = 1000;
        parm.parm.capture.timeperframe.denominator =
            (fps * 1000.0).round().clamp(1.0, f64::from(u32::MAX)) as u32;
        ioctl(handle, vidioc::VIDIOC_S_PARM, &mut parm)
            .map_err(|e| named_on(api, "VIDIOC_S_PARM", e))
    }
}

/// One plane's payload in a dequeued buffer and the bytes between its rows.
#[derive(Clone, Copy, Debug)]
pub struct PlaneData<'a> {
    pub bytes: &'a [u8],
    pub stride: usize,
}

/// The bytes of a row and the rows of each plane of `format` when it comes in `planes`
/// separate planes; `None` for a plane count the format does not come in.
pub(super) fn plane_rows(
    format: PixelFormat,
    width: u32,
    height: u32,
    planes: usize,
) -> Option<Vec<(usize, usize)>> {
    let (w, h) = (width as usize, height as usize);
    match (format, planes) {
        (_, 1) => Some(vec![(format.row_bytes(width), h)]),
        (PixelFormat::PlanarYuv(layout), 2) if layout.interleaved() => {
            // A pair per pixel (4:4:4) or per two; samples of one byte or two (P010).
            let sample = layout.sample_bytes();
            let row = 2 * w / layout.pixels_per_chroma_pair() * sample;
            Some(vec![
                (w * sample, h),
                (row, h / layout.rows_per_chroma_row()),
            ])
        }
        (PixelFormat::PlanarYuv(layout), 3) if !layout.interleaved() => {
            let chroma = (
                w / layout.pixels_per_chroma_pair(),
                h / layout.rows_per_chroma_row(),
            );
            Some(vec![(w, h), chroma, chroma])
        }
        _ => None,
    }
}

/// Copies a frame that came in separate planes (luma, then chroma in the driver's order) into
/// the one-buffer layout of its twin with packed rows: `out` holds plane after plane, each row
/// `row bytes` long ([`MplaneFormat::stride`]). Planes too short for their rows, or a plane
/// count the format does not come in, are errors that say which plane and what.
pub fn gather_planes(
    format: PixelFormat,
    width: u32,
    height: u32,
    planes: &[PlaneData<'_>],
    out: &mut Vec<u8>,
) -> Result<(), String> {
    let rows = plane_rows(format, width, height, planes.len())
        .ok_or_else(|| format!("{format} does not come in {} planes", planes.len()))?;
    out.clear();
    for (i, (plane, &(row_bytes, count))) in planes.iter().zip(&rows).enumerate() {
        if count == 0 || row_bytes == 0 {
            continue;
        }
        if plane.stride < row_bytes {
            return Err(format!(
                "plane {i}: {} bytes per line, less than a row of {row_bytes}",
                plane.stride
            ));
        }
        let needed = (count - 1)
            .checked_mul(plane.stride)
            .and_then(|v| v.checked_add(row_bytes));
        if needed.is_none_or(|n| plane.bytes.len() < n) {
            return Err(format!(
                "plane {i}: {} bytes, {count} rows of {row_bytes} at {} bytes per line need {}",
                plane.bytes.len(),
                plane.stride,
                needed.map_or("more".to_string(), |n| n.to_string())
            ));
        }
        for row in plane.bytes.chunks(plane.stride).take(count) {
            out.extend_from_slice(&row[..row_bytes]);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::pixel_format::{BayerPattern, PackedYuv, PlanarYuv};

    #[test]
    fn separate_plane_codes_name_their_one_buffer_twins() {
        let yuv = |layout| Some(PixelFormat::PlanarYuv(layout));
        for (code, want) in [
            (*b"NM12", yuv(PlanarYuv::Nv12)),
            (*b"NM21", yuv(PlanarYuv::Nv21)),
            (*b"YM12", yuv(PlanarYuv::Yu12)),
            (*b"YM21", yuv(PlanarYuv::Yv12)),
            (*b"NM16", yuv(PlanarYuv::Nv16)),
            (*b"YM16", yuv(PlanarYuv::Yuv422p)),
            // Three-plane layouts without a one-buffer code stand for themselves.
            (*b"YM61", yuv(PlanarYuv::Yvu422p)),
            (*b"YM24", yuv(PlanarYuv::Yuv444p)),
            (*b"YM42", yuv(PlanarYuv::Yvu444p)),
            // Codes a multi-planar node offers in one plane are read as on any node.
            (*b"NV12", yuv(PlanarYuv::Nv12)),
            (
                *b"pRAA",
                Some(PixelFormat::Csi2Packed {
                    pattern: Some(BayerPattern::Rggb),
                    bits: 10,
                }),
            ),
            (*b"AYUV", Some(PixelFormat::PackedYuv(PackedYuv::Ayuv32))),
            // Packed 4:4:4 of 4 bits a sample: not converted.
            (*b"Y444", None),
        ] {
            assert_eq!(
                pixel_format(code),
                want,
                "{}",
                String::from_utf8_lossy(&code)
            );
        }
    }

    /// The planes' row bytes and rows: NV12 in two planes, P010's of 16-bit words twice as
    /// long, YU12 in three; a plane count the format does not come in is `None`.
    #[test]
    fn plane_rows_count_bytes_of_every_sample_size() {
        let nv12 = PixelFormat::PlanarYuv(PlanarYuv::Nv12);
        let p010 = PixelFormat::PlanarYuv(PlanarYuv::P010);
        let yu12 = PixelFormat::PlanarYuv(PlanarYuv::Yu12);
        assert_eq!(plane_rows(nv12, 8, 4, 2), Some(vec![(8, 4), (8, 2)]));
        assert_eq!(plane_rows(p010, 8, 4, 2), Some(vec![(16, 4), (16, 2)]));
        assert_eq!(plane_rows(p010, 8, 4, 1), Some(vec![(16, 4)]));
        assert_eq!(
            plane_rows(yu12, 8, 4, 3),
            Some(vec![(8, 4), (4, 2), (4, 2)])
        );
        assert_eq!(plane_rows(yu12, 8, 4, 2), None);
    }

    /// Spreads a one-buffer frame with packed rows over padded planes, as a driver would.
    fn padded_planes(
        packed: &[u8],
        rows: &[(usize, usize)],
        pads: &[usize],
    ) -> Vec<(Vec<u8>, usize)> {
        let mut at = 0;
        rows.iter()
            .zip(pads)
            .map(|(&(row_bytes, count), &pad)| {
                let stride = row_bytes + pad;
                let mut plane = vec![0xEE; stride * count];
                for r in 0..count {
                    plane[r * stride..r * stride + row_bytes]
                        .copy_from_slice(&packed[at..at + row_bytes]);
                    at += row_bytes;
                }
                (plane, stride)
            })
            .collect()
    }

    #[test]
    fn gathered_planes_are_the_one_buffer_frame() {
        use crate::capture::pixel_format::{decode_into, CodeImage, RawFrame, YuvMatrix};
        let (w, h) = (6u32, 4u32);
        for (layout, rows) in [
            (PlanarYuv::Nv12, vec![(6, 4), (6, 2)]),
            (PlanarYuv::Nv21, vec![(6, 4), (6, 2)]),
            (PlanarYuv::Yu12, vec![(6, 4), (3, 2), (3, 2)]),
            (PlanarYuv::Yv12, vec![(6, 4), (3, 2), (3, 2)]),
            (PlanarYuv::Nv16, vec![(6, 4), (6, 4)]),
            (PlanarYuv::Nv61, vec![(6, 4), (6, 4)]),
            (PlanarYuv::Yuv422p, vec![(6, 4), (3, 4), (3, 4)]),
            (PlanarYuv::Yvu422p, vec![(6, 4), (3, 4), (3, 4)]),
            (PlanarYuv::Yuv444p, vec![(6, 4), (6, 4), (6, 4)]),
            (PlanarYuv::Yvu444p, vec![(6, 4), (6, 4), (6, 4)]),
        ] {
            let format = PixelFormat::PlanarYuv(layout);
            let len = format.buffer_len(w, h, 0).unwrap();
            let packed: Vec<u8> = (0..len).map(|i| (i * 37 % 251) as u8).collect();
            let pads = [2, 10, 4];
            let planes = padded_planes(&packed, &rows, &pads);
            let views: Vec<PlaneData<'_>> = planes
                .iter()
                .map(|(bytes, stride)| PlaneData {
                    bytes,
                    stride: *stride,
                })
                .collect();
            let mut out = vec![1, 2, 3];
            gather_planes(format, w, h, &views, &mut out).unwrap();
            assert_eq!(out, packed, "{layout:?}");
            // And it decodes as the one-buffer frame at the stride the stream reports.
            let stride = MplaneFormat {
                fourcc: *b"NM12",
                width: w,
                height: h,
                colorspace: 0,
                strides: vec![8; rows.len()],
            }
            .stride(format);
            assert_eq!(stride, 6);
            let raw = |data| RawFrame {
                data,
                format,
                width: w,
                height: h,
                stride,
            };
            let (mut a, mut b) = (CodeImage::default(), CodeImage::default());
            decode_into(&raw(&out), YuvMatrix::Bt709, &mut a).unwrap();
            decode_into(&raw(&packed), YuvMatrix::Bt709, &mut b).unwrap();
            assert_eq!(a, b);
        }
    }

    #[test]
    fn short_or_miscounted_planes_are_errors_that_say_which() {
        let format = PixelFormat::PlanarYuv(PlanarYuv::Nv12);
        let luma = vec![0u8; 8 * 4];
        let chroma = vec![0u8; 8 * 2 - 3];
        let mut out = Vec::new();
        let planes = [
            PlaneData {
                bytes: &luma,
                stride: 8,
            },
            PlaneData {
                bytes: &chroma,
                stride: 8,
            },
        ];
        let e = gather_planes(format, 8, 4, &planes, &mut out).unwrap_err();
        assert!(e.starts_with("plane 1: 13 bytes"), "{e}");
        let narrow = [
            PlaneData {
                bytes: &luma,
                stride: 4,
            },
            PlaneData {
                bytes: &luma,
                stride: 8,
            },
        ];
        let e = gather_planes(format, 8, 4, &narrow, &mut out).unwrap_err();
        assert!(
            e.contains("plane 0: 4 bytes per line, less than a row of 8"),
            "{e}"
        );
        let e = gather_planes(format, 8, 4, &planes[..1].repeat(3), &mut out).unwrap_err();
        assert!(e.contains("does not come in 3 planes"), "{e}");
        let grey = PixelFormat::Grey { bits: 8 };
        assert!(gather_planes(grey, 8, 4, &planes, &mut out).is_err());
    }

    /// Every call on a file that is no V4L2 node fails with an error naming the request (no
    /// panic). tests/fake_v4l2.rs runs them against a fake driver.
    #[test]
    fn calls_on_a_file_that_is_no_v4l2_node_fail_naming_the_request() {
        let device = v4l::Device::with_path("/dev/null").unwrap();
        let handle = device.handle();
        let e = enum_formats(&handle, CaptureApi::MultiPlanar).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("VIDIOC_ENUM_FMT (multi-planar): "),
            "{e}"
        );
        let e = enum_formats(&handle, CaptureApi::SinglePlanar).unwrap_err();
        assert!(e.to_string().starts_with("VIDIOC_ENUM_FMT: "), "{e}");
        let e = set_format(&handle, *b"NM12", 640, 480).unwrap_err();
        assert!(
            e.to_string().starts_with("VIDIOC_G_FMT (multi-planar): "),
            "{e}"
        );
        let e = set_frame_rate(&handle, CaptureApi::MultiPlanar, 30.0).unwrap_err();
        assert!(
            e.to_string().starts_with("VIDIOC_G_PARM (multi-planar): "),
            "{e}"
        );
    }

    #[test]
    fn the_stride_is_the_drivers_for_one_plane_and_packed_for_several() {
        let one = MplaneFormat {
            fourcc: *b"pRAA",
            width: 640,
            height: 480,
            colorspace: 0,
            strides: vec![832],
        };
        let raw10 = PixelFormat::Csi2Packed {
            pattern: Some(BayerPattern::Rggb),
            bits: 10,
        };
        assert_eq!(one.stride(raw10), 832);
        let two = MplaneFormat {
            fourcc: *b"NM12",
            strides: vec![704, 704],
            ..one
        };
        assert_eq!(two.stride(PixelFormat::PlanarYuv(PlanarYuv::Nv12)), 640);
    }
}
