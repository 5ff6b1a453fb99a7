//! Capture through V4L2's multi-planar API (`V4L2_BUF_TYPE_VIDEO_CAPTURE_MPLANE`), the one that
//! SoC camera pipelines use (Rockchip's ISP, NXP i.MX, Allwinner, the Raspberry Pi ISP and many
//! other MIPI CSI-2 receivers): a frame is one buffer made of up to eight planes, each mapped on
//! its own. The `v4l` crate streams single-planar buffers only, so this module makes the calls
//! itself, with the crate's ioctl wrapper and the kernel's structures (`v4l::v4l_sys`):
//!
//! 1. [`enum_formats`]: `VIDIOC_ENUM_FMT` for the multi-planar buffer type. Formats whose planes
//!    are separate buffers have their own codes (`NM12` is NV12 with the luma and the chroma in
//!    two planes, `YM12` YUV 4:2:0 in three); [`pixel_format`] names each by the pixel format of
//!    its one-buffer twin, so `formats = ["NV12"]` in the config takes `NM12` too;
//! 2. [`set_format`]: `VIDIOC_G_FMT` then `VIDIOC_S_FMT` with `v4l2_pix_format_mplane`; the
//!    driver's answer gives the planes' count and their bytes per line;
//!    [`set_frame_rate`]: `VIDIOC_S_PARM`;
//! 3. [`MplaneStream`]: `VIDIOC_REQBUFS` (memory-mapped), `VIDIOC_QUERYBUF` with a plane array
//!    and one `mmap` per plane; every buffer queued, `VIDIOC_STREAMON`; per frame the previous
//!    buffer is queued again, `poll` waits (with the timeout), `VIDIOC_DQBUF` returns the next
//!    with each plane's payload (`bytesused`, starting at `data_offset`);
//! 4. a frame in one plane is handed on where the driver wrote it; a frame in several planes is
//!    copied by [`gather_planes`] into the one-buffer layout of its twin with rows packed
//!    (stride = row bytes), so everything after the buffer is the same code as for a
//!    single-planar camera.
//!
//! Dropping the stream stops it, unmaps the planes and frees the buffers; errors there (the
//! device gone) are logged, never a panic. Retried on `EINTR`: `poll` and `VIDIOC_DQBUF`, which
//! a signal to the daemon (SIGHUP) may interrupt.

use super::pixel_format::PixelFormat;
use std::io;
use std::os::raw::c_void;
use std::ptr::NonNull;
use std::sync::Arc;
use std::time::Duration;
use v4l::buffer::Metadata;
use v4l::device::Handle;
use v4l::v4l2;
use v4l::v4l2::vidioc;
use v4l::v4l_sys::{
    v4l2_buffer, v4l2_fmtdesc, v4l2_format, v4l2_plane, v4l2_requestbuffers, v4l2_streamparm,
};

/// `V4L2_BUF_TYPE_VIDEO_CAPTURE_MPLANE`.
pub const CAPTURE_MPLANE: u32 = 9;
/// `V4L2_MEMORY_MMAP`.
const MEMORY_MMAP: u32 = 1;
/// `VIDEO_MAX_PLANES`: the length of every plane array the kernel reads or writes.
const MAX_PLANES: usize = 8;
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

/// One plane of a negotiated format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlaneFormat {
    pub bytes_per_line: u32,
    pub size_image: u32,
}

/// A format the driver set on a multi-planar node.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MplaneFormat {
    pub fourcc: [u8; 4],
    pub width: u32,
    pub height: u32,
    /// `V4L2_COLORSPACE_*`.
    pub colorspace: u32,
    pub planes: Vec<PlaneFormat>,
}

impl MplaneFormat {
    /// The bytes between rows of the frame as [`MplaneStream::next_frame`] hands it on: the driver's
    /// for a one-plane format, packed rows (the row's bytes) for a gathered one.
    pub fn stride(&self, format: PixelFormat) -> usize {
        match self.planes.as_slice() {
            [one] => one.bytes_per_line as usize,
            _ => format.row_bytes(self.width),
        }
    }
}

fn fourcc_u32(code: [u8; 4]) -> u32 {
    u32::from_le_bytes(code)
}

/// # Safety
/// `arg` must be the structure that `request` reads and writes.
unsafe fn ioctl<T>(handle: &Handle, request: vidioc::_IOC_TYPE, arg: &mut T) -> io::Result<()> {
    // SAFETY: the caller pairs the request with its structure; the kernel writes within it.
    unsafe { v4l2::ioctl(handle.fd(), request, arg as *mut T as *mut c_void) }
}

fn named(what: &str, e: io::Error) -> io::Error {
    io::Error::new(e.kind(), format!("{what}: {e}"))
}

/// The formats of a multi-planar capture node: its fourcc and the driver's description.
pub fn enum_formats(handle: &Handle) -> io::Result<Vec<([u8; 4], String)>> {
    let mut formats = Vec::new();
    // A driver lists a few dozen at most; the bound keeps a broken one from looping forever.
    for index in 0..256 {
        // SAFETY: all-zero is a valid v4l2_fmtdesc (plain integers and bytes).
        let mut desc: v4l2_fmtdesc = unsafe { std::mem::zeroed() };
        desc.index = index;
        desc.type_ = CAPTURE_MPLANE;
        // SAFETY: VIDIOC_ENUM_FMT reads and writes a v4l2_fmtdesc.
        match unsafe { ioctl(handle, vidioc::VIDIOC_ENUM_FMT, &mut desc) } {
            Ok(()) => {}
            Err(e) if e.raw_os_error() == Some(libc::EINVAL) => break,
            Err(e) => return Err(named("VIDIOC_ENUM_FMT (multi-planar)", e)),
        }
        let text = desc.description;
        let end = text.iter().position(|&b| b == 0).unwrap_or(text.len());
        formats.push((
            desc.pixelformat.to_le_bytes(),
            String::from_utf8_lossy(&text[..end]).into_owned(),
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
        format.fmt.pix_mp.pixelformat = fourcc_u32(fourcc);
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
        planes: pix.plane_fmt[..count]
            .iter()
            .map(|p| PlaneFormat {
                bytes_per_line: p.bytesperline,
                size_image: p.sizeimage,
            })
            .collect(),
    })
}

/// Asks for `fps` frames a second (`VIDIOC_S_PARM`); an error where the driver takes no frame
/// interval.
pub fn set_frame_rate(handle: &Handle, fps: f64) -> io::Result<()> {
    // SAFETY: all-zero is a valid v4l2_streamparm.
    let mut parm: v4l2_streamparm = unsafe { std::mem::zeroed() };
    parm.type_ = CAPTURE_MPLANE;
    // SAFETY: VIDIOC_G_PARM / VIDIOC_S_PARM read and write a v4l2_streamparm; for a capture
    // buffer type the union holds `capture`.
    unsafe {
        ioctl(handle, vidioc::VIDIOC_G_PARM, &mut parm)
            .map_err(|e| named("VIDIOC_G_PARM (multi-planar)", e))?;
        if parm.parm.capture.capability & CAP_TIMEPERFRAME == 0 {
            return Err(io::Error::new(
                io::ErrorKind::Unsupported,
                "VIDIOC_S_PARM (multi-planar): the driver sets no frame interval",
            ));
        }
        parm.parm.capture.timeperframe.numerator = 1000;
        parm.parm.capture.timeperframe.denominator =
            (fps * 1000.0).round().clamp(1.0, f64::from(u32::MAX)) as u32;
        ioctl(handle, vidioc::VIDIOC_S_PARM, &mut parm)
            .map_err(|e| named("VIDIOC_S_PARM (multi-planar)", e))
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
fn plane_rows(
    format: PixelFormat,
    width: u32,
    height: u32,
    planes: usize,
) -> Option<Vec<(usize, usize)>> {
    let (w, h) = (width as usize, height as usize);
    match (format, planes) {
        (_, 1) => Some(vec![(format.row_bytes(width), h)]),
        (PixelFormat::PlanarYuv(layout), 2) if layout.interleaved() => {
            Some(vec![(w, h), (w, h / layout.rows_per_chroma_row())])
        }
        (PixelFormat::PlanarYuv(layout), 3) if !layout.interleaved() => {
            let chroma = (w / 2, h / layout.rows_per_chroma_row());
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

/// One memory-mapped plane.
struct Mapping {
    start: NonNull<u8>,
    len: usize,
}

// SAFETY: a mapping is owned by its stream alone, read only through `&mut MplaneStream`, and
// unmapped once, when the stream is dropped; nothing about it is tied to a thread.
unsafe impl Send for Mapping {}

impl Mapping {
    fn bytes(&self) -> &[u8] {
        // SAFETY: `start` is a live mapping of `len` bytes until `Drop` unmaps it.
        unsafe { std::slice::from_raw_parts(self.start.as_ptr(), self.len) }
    }
}

/// Memory-mapped streaming from a multi-planar capture node (see the module docs).
pub struct MplaneStream {
    handle: Arc<Handle>,
    /// Per buffer, its planes.
    buffers: Vec<Vec<Mapping>>,
    plane_count: usize,
    format: PixelFormat,
    width: u32,
    height: u32,
    timeout_ms: i32,
    streaming: bool,
    /// The buffer handed out last, queued again on the next call.
    lent: Option<usize>,
    /// Per plane of the last buffer: (payload start, payload end, bytes per line).
    payload: Vec<(usize, usize, usize)>,
    strides: Vec<usize>,
    gathered: Vec<u8>,
}

impl MplaneStream {
    /// Requests and maps `count` buffers of the negotiated `format`, whose pixels are `pixel`.
    pub fn new(
        handle: Arc<Handle>,
        format: &MplaneFormat,
        pixel: PixelFormat,
        count: u32,
    ) -> io::Result<Self> {
        let plane_count = format.planes.len();
        if plane_rows(pixel, format.width, format.height, plane_count).is_none() {
            return Err(io::Error::new(
                io::ErrorKind::Unsupported,
                format!("{pixel} in {plane_count} planes is not supported"),
            ));
        }
        // SAFETY: all-zero is a valid v4l2_requestbuffers.
        let mut request: v4l2_requestbuffers = unsafe { std::mem::zeroed() };
        request.count = count;
        request.type_ = CAPTURE_MPLANE;
        request.memory = MEMORY_MMAP;
        // SAFETY: VIDIOC_REQBUFS reads and writes a v4l2_requestbuffers.
        unsafe { ioctl(&handle, vidioc::VIDIOC_REQBUFS, &mut request) }
            .map_err(|e| named("VIDIOC_REQBUFS (multi-planar)", e))?;
        let mut stream = Self {
            handle,
            buffers: Vec::new(),
            plane_count,
            format: pixel,
            width: format.width,
            height: format.height,
            timeout_ms: -1,
            streaming: false,
            lent: None,
            payload: Vec::new(),
            strides: format
                .planes
                .iter()
                .map(|p| p.bytes_per_line as usize)
                .collect(),
            gathered: Vec::new(),
        };
        // From here on `Drop` unmaps what was mapped (each plane as soon as it is) and frees
        // the buffers.
        let fd = stream.handle.fd();
        for index in 0..request.count {
            let mut planes = [zeroed_plane(); MAX_PLANES];
            let mut buffer = stream.buffer_desc(index, &mut planes);
            // SAFETY: VIDIOC_QUERYBUF reads and writes a v4l2_buffer whose `m.planes` points
            // at `length` planes, here an array of MAX_PLANES that outlives the call.
            unsafe { ioctl(&stream.handle, vidioc::VIDIOC_QUERYBUF, &mut buffer) }
                .map_err(|e| named("VIDIOC_QUERYBUF (multi-planar)", e))?;
            stream.buffers.push(Vec::with_capacity(plane_count));
            for plane in &planes[..plane_count] {
                let len = plane.length as usize;
                // SAFETY: the union holds `mem_offset` for memory-mapped buffers.
                let offset = unsafe { plane.m.mem_offset };
                // SAFETY: maps `len` bytes of the device at the offset the driver gave; the
                // result is checked and unmapped in `Drop`.
                let start = unsafe {
                    v4l2::mmap(
                        std::ptr::null_mut(),
                        len,
                        libc::PROT_READ | libc::PROT_WRITE,
                        libc::MAP_SHARED,
                        fd,
                        offset as libc::off_t,
                    )
                }
                .map_err(|e| named("mmap of a plane", e))?;
                let start = NonNull::new(start.cast::<u8>())
                    .ok_or_else(|| io::Error::other("mmap of a plane returned a null address"))?;
                if let Some(mapped) = stream.buffers.last_mut() {
                    mapped.push(Mapping { start, len });
                }
            }
        }
        if stream.buffers.is_empty() {
            return Err(io::Error::other(
                "VIDIOC_REQBUFS (multi-planar): the driver gave no buffers",
            ));
        }
        Ok(stream)
    }

    /// How long [`next_frame`](Self::next_frame) waits for a frame before it fails with `TimedOut`.
    pub fn set_timeout(&mut self, timeout: Duration) {
        self.timeout_ms = timeout.as_millis().min(i32::MAX as u128) as i32;
    }

    fn buffer_desc(&self, index: u32, planes: &mut [v4l2_plane; MAX_PLANES]) -> v4l2_buffer {
        // SAFETY: all-zero is a valid v4l2_buffer (integers, a timeval and unions).
        let mut buffer: v4l2_buffer = unsafe { std::mem::zeroed() };
        buffer.index = index;
        buffer.type_ = CAPTURE_MPLANE;
        buffer.memory = MEMORY_MMAP;
        buffer.m.planes = planes.as_mut_ptr();
        buffer.length = self.plane_count as u32;
        buffer
    }

    fn queue(&mut self, index: usize) -> io::Result<()> {
        let mut planes = [zeroed_plane(); MAX_PLANES];
        let mut buffer = self.buffer_desc(index as u32, &mut planes);
        // SAFETY: VIDIOC_QBUF reads a v4l2_buffer with its plane array (see `new`).
        unsafe { ioctl(&self.handle, vidioc::VIDIOC_QBUF, &mut buffer) }
            .map_err(|e| named("VIDIOC_QBUF (multi-planar)", e))
    }

    /// Waits for the next frame and returns it — the driver's plane for a one-plane format,
    /// the planes gathered into one buffer otherwise — with its metadata (`bytesused` is the
    /// length of the bytes returned). The bytes are `Err` with the reason for a buffer that
    /// holds no usable frame: flagged corrupt, empty, or planes too short for the format.
    pub fn next_frame(&mut self) -> io::Result<(Result<&[u8], String>, Metadata)> {
        if self.streaming {
            if let Some(index) = self.lent.take() {
                self.queue(index)?;
            }
        } else {
            for index in 0..self.buffers.len() {
                self.queue(index)?;
            }
            let mut kind = CAPTURE_MPLANE as libc::c_int;
            // SAFETY: VIDIOC_STREAMON reads the buffer type as an int.
            unsafe { ioctl(&self.handle, vidioc::VIDIOC_STREAMON, &mut kind) }
                .map_err(|e| named("VIDIOC_STREAMON (multi-planar)", e))?;
            self.streaming = true;
        }
        loop {
            match self.handle.poll(libc::POLLIN, self.timeout_ms) {
                Ok(0) => {
                    return Err(io::Error::new(
                        io::ErrorKind::TimedOut,
                        "VIDIOC_DQBUF (multi-planar): no frame within the timeout",
                    ))
                }
                Ok(_) => break,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(named("poll", e)),
            }
        }
        let mut planes = [zeroed_plane(); MAX_PLANES];
        let mut buffer = self.buffer_desc(0, &mut planes);
        loop {
            // SAFETY: VIDIOC_DQBUF writes a v4l2_buffer and its plane array (see `new`).
            match unsafe { ioctl(&self.handle, vidioc::VIDIOC_DQBUF, &mut buffer) } {
                Ok(()) => break,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(named("VIDIOC_DQBUF (multi-planar)", e)),
            }
        }
        let index = buffer.index as usize;
        let Some(mapped) = self.buffers.get(index) else {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                format!(
                    "VIDIOC_DQBUF (multi-planar): buffer {index} of {}",
                    self.buffers.len()
                ),
            ));
        };
        self.lent = Some(index);
        self.payload.clear();
        for ((plane, mapping), &stride) in planes.iter().zip(mapped).zip(&self.strides) {
            let end = (plane.bytesused as usize).min(mapping.len);
            let start = (plane.data_offset as usize).min(end);
            self.payload.push((start, end, stride));
        }
        let mut meta = Metadata {
            bytesused: 0,
            flags: buffer.flags.into(),
            field: buffer.field,
            timestamp: buffer.timestamp.into(),
            sequence: buffer.sequence,
        };
        let data = if meta.flags.contains(v4l::buffer::Flags::ERROR) {
            Err("the driver flagged the buffer as corrupt".to_string())
        } else if let Some(i) = self.payload.iter().position(|&(s, e, _)| s == e) {
            Err(format!("plane {i} of the buffer is empty"))
        } else if let [(start, end, _)] = self.payload[..] {
            Ok(&mapped[0].bytes()[start..end])
        } else {
            let planes: Vec<PlaneData<'_>> = self
                .payload
                .iter()
                .zip(mapped)
                .map(|(&(start, end, stride), mapping)| PlaneData {
                    bytes: &mapping.bytes()[start..end],
                    stride,
                })
                .collect();
            gather_planes(
                self.format,
                self.width,
                self.height,
                &planes,
                &mut self.gathered,
            )
            .map(|()| self.gathered.as_slice())
        };
        if let Ok(bytes) = &data {
            meta.bytesused = bytes.len() as u32;
        }
        Ok((data, meta))
    }
}

fn zeroed_plane() -> v4l2_plane {
    // SAFETY: all-zero is a valid v4l2_plane (integers and a union of integers).
    unsafe { std::mem::zeroed() }
}

impl Drop for MplaneStream {
    fn drop(&mut self) {
        let mut problems = Vec::new();
        if self.streaming {
            let mut kind = CAPTURE_MPLANE as libc::c_int;
            // SAFETY: VIDIOC_STREAMOFF reads the buffer type as an int.
            if let Err(e) = unsafe { ioctl(&self.handle, vidioc::VIDIOC_STREAMOFF, &mut kind) } {
                problems.push(format!("VIDIOC_STREAMOFF: {e}"));
            }
        }
        for mapping in self.buffers.drain(..).flatten() {
            // SAFETY: a live mapping made in `new`, unmapped once, here.
            if let Err(e) = unsafe { v4l2::munmap(mapping.start.as_ptr().cast(), mapping.len) } {
                problems.push(format!("munmap: {e}"));
            }
        }
        // SAFETY: all-zero is a valid v4l2_requestbuffers; count 0 frees the buffers.
        let mut request: v4l2_requestbuffers = unsafe { std::mem::zeroed() };
        request.type_ = CAPTURE_MPLANE;
        request.memory = MEMORY_MMAP;
        // SAFETY: VIDIOC_REQBUFS reads and writes a v4l2_requestbuffers.
        if let Err(e) = unsafe { ioctl(&self.handle, vidioc::VIDIOC_REQBUFS, &mut request) } {
            problems.push(format!("VIDIOC_REQBUFS 0: {e}"));
        }
        if !problems.is_empty() {
            tracing::warn!(
                "closing the multi-planar stream (fd {}): {} (device gone?)",
                self.handle.fd(),
                problems.join("; ")
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::pixel_format::{BayerPattern, PlanarYuv};

    #[test]
    fn separate_plane_codes_name_their_one_buffer_twins() {
        assert_eq!(
            pixel_format(*b"NM12"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Nv12))
        );
        assert_eq!(
            pixel_format(*b"NM21"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Nv21))
        );
        assert_eq!(
            pixel_format(*b"YM12"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Yu12))
        );
        assert_eq!(
            pixel_format(*b"YM21"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Yv12))
        );
        // Codes a multi-planar node offers in one plane are read as on any node.
        assert_eq!(
            pixel_format(*b"NV12"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Nv12))
        );
        assert_eq!(
            pixel_format(*b"pRAA"),
            Some(PixelFormat::Csi2Packed {
                pattern: Some(BayerPattern::Rggb),
                bits: 10
            })
        );
        assert_eq!(
            pixel_format(*b"NM16"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Nv16))
        );
        assert_eq!(
            pixel_format(*b"YM16"),
            Some(PixelFormat::PlanarYuv(PlanarYuv::Yuv422p))
        );
        // YVU 4:2:2 in three planes has no one-buffer twin in V4L2: not converted.
        assert_eq!(pixel_format(*b"YM61"), None);
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
                planes: vec![
                    PlaneFormat {
                        bytes_per_line: 8,
                        size_image: 0
                    };
                    rows.len()
                ],
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
    /// panic, nothing mapped). A real node is not available on the machines the tests run on.
    #[test]
    fn calls_on_a_file_that_is_no_v4l2_node_fail_naming_the_request() {
        let device = v4l::Device::with_path("/dev/null").unwrap();
        let handle = device.handle();
        let e = enum_formats(&handle).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("VIDIOC_ENUM_FMT (multi-planar): "),
            "{e}"
        );
        let e = set_format(&handle, *b"NM12", 640, 480).unwrap_err();
        assert!(
            e.to_string().starts_with("VIDIOC_G_FMT (multi-planar): "),
            "{e}"
        );
        let e = set_frame_rate(&handle, 30.0).unwrap_err();
        assert!(
            e.to_string().starts_with("VIDIOC_G_PARM (multi-planar): "),
            "{e}"
        );
        let format = MplaneFormat {
            fourcc: *b"NM12",
            width: 640,
            height: 480,
            colorspace: 0,
            planes: vec![
                PlaneFormat {
                    bytes_per_line: 640,
                    size_image: 640 * 480
                };
                2
            ],
        };
        let nv12 = PixelFormat::PlanarYuv(PlanarYuv::Nv12);
        let e = MplaneStream::new(handle.clone(), &format, nv12, 4)
            .err()
            .unwrap();
        assert!(
            e.to_string().starts_with("VIDIOC_REQBUFS (multi-planar): "),
            "{e}"
        );
        // A plane count the format does not come in is refused before any request.
        let grey = PixelFormat::Grey { bits: 8 };
        let e = MplaneStream::new(handle, &format, grey, 4).err().unwrap();
        assert!(
            e.to_string().contains("in 2 planes is not supported"),
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
            planes: vec![PlaneFormat {
                bytes_per_line: 832,
                size_image: 832 * 480,
            }],
        };
        let raw10 = PixelFormat::Csi2Packed {
            pattern: Some(BayerPattern::Rggb),
            bits: 10,
        };
        assert_eq!(one.stride(raw10), 832);
        let two = MplaneFormat {
            fourcc: *b"NM12",
            planes: vec![
                PlaneFormat {
                    bytes_per_line: 704,
                    size_image: 0
                };
                2
            ],
            ..one
        };
        assert_eq!(two.stride(PixelFormat::PlanarYuv(PlanarYuv::Nv12)), 640);
    }
}
