//! Memory-mapped streaming from a V4L2 capture node, single- or multi-planar
//! ([`MmapStream`]), with the kernel's structures (`v4l::v4l_sys`) and the `v4l` crate's ioctl
//! wrapper. envlight streams through its own code rather than the `v4l` crate's stream, which
//! handles single-planar buffers only and panics when stopping a stream fails with anything
//! but ENODEV; its buffers' `Drop` then panicked again while unwinding (videobuf2 refuses to
//! free the buffers of a queue still streaming: EBUSY), which aborted the process.
//!
//! 1. [`MmapStream::new`]: `VIDIOC_REQBUFS` (memory-mapped buffers), then per buffer
//!    `VIDIOC_QUERYBUF` (for the multi-planar type with a plane array) and one `mmap` per
//!    plane;
//! 2. the first [`MmapStream::next_frame`] queues every buffer and starts the stream
//!    (`VIDIOC_STREAMON`); each later call queues the buffer handed out before;
//! 3. `poll` waits for a frame (with the timeout), `VIDIOC_DQBUF` takes it; a signal
//!    (`EINTR`) retries the call, a wake-up with no buffer ready (`EAGAIN`) polls again, all
//!    within the one timeout;
//! 4. the payload is each plane's bytes from its `data_offset` to its `bytesused` (a
//!    single-planar buffer's from 0 to `bytesused`): a frame in one plane is handed on where the
//!    driver wrote it, a frame in several planes is copied into the one-buffer layout of its
//!    format ([`gather_planes`]); a buffer the driver flags corrupt, an empty one or planes
//!    too short are reported as such, for the caller to skip;
//! 5. dropping the stream stops it, unmaps every plane and frees the buffers; what fails there
//!    (a device that is gone) is logged, never a panic.

use super::pixel_format::PixelFormat;
use super::v4l2::CaptureApi;
use super::v4l2_mplane::{gather_planes, plane_rows, PlaneData};
use std::io;
use std::os::raw::c_void;
use std::ptr::NonNull;
use std::sync::Arc;
use std::time::{Duration, Instant};
use v4l::buffer::Metadata;
use v4l::device::Handle;
use v4l::v4l2;
use v4l::v4l2::vidioc;
use v4l::v4l_sys::{v4l2_buffer, v4l2_plane, v4l2_requestbuffers};

/// `V4L2_BUF_TYPE_VIDEO_CAPTURE`.
pub const CAPTURE: u32 = 1;
/// `V4L2_BUF_TYPE_VIDEO_CAPTURE_MPLANE`.
pub const CAPTURE_MPLANE: u32 = 9;
/// `V4L2_MEMORY_MMAP`.
const MEMORY_MMAP: u32 = 1;
/// `VIDEO_MAX_PLANES`: the most planes of a format, and the length of every plane array the
/// kernel reads or writes.
pub const MAX_PLANES: usize = 8;

/// # Safety
/// `arg` must be the structure that `request` reads and writes.
pub(super) unsafe fn ioctl<T>(
    handle: &Handle,
    request: vidioc::_IOC_TYPE,
    arg: &mut T,
) -> io::Result<()> {
    // SAFETY: the caller pairs the request with its structure; the kernel writes within it.
    unsafe { v4l2::ioctl(handle.fd(), request, arg as *mut T as *mut c_void) }
}

/// `e` with `what` (the request) in front.
pub(super) fn named(what: &str, e: io::Error) -> io::Error {
    io::Error::new(e.kind(), format!("{what}: {e}"))
}

/// `e` named by `request` made through `api` (which is said where it is the multi-planar one).
pub(super) fn named_on(api: CaptureApi, request: &str, e: io::Error) -> io::Error {
    match api {
        CaptureApi::SinglePlanar => named(request, e),
        CaptureApi::MultiPlanar => named(&format!("{request} (multi-planar)"), e),
    }
}

/// A fixed-size string of a kernel structure, up to its NUL, read lossily: drivers cut names
/// at the field's length, in the middle of a UTF-8 sequence where a name is not ASCII (a USB
/// camera's product name in Chinese, say).
pub(super) fn kernel_string(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

/// One memory-mapped plane.
struct Mapping {
    start: NonNull<u8>,
    len: usize,
}

// SAFETY: a mapping is owned by its stream alone, read only through `&mut MmapStream`, and
// unmapped once, when the stream is dropped; nothing about it is tied to a thread.
unsafe impl Send for Mapping {}

impl Mapping {
    fn bytes(&self) -> &[u8] {
        // SAFETY: `start` is a live mapping of `len` bytes until `Drop` unmaps it.
        unsafe { std::slice::from_raw_parts(self.start.as_ptr(), self.len) }
    }
}

fn zeroed_plane() -> v4l2_plane {
    // SAFETY: all-zero is a valid v4l2_plane (integers and a union of integers).
    unsafe { std::mem::zeroed() }
}

/// Memory-mapped streaming from a capture node (see the module docs).
pub struct MmapStream {
    handle: Arc<Handle>,
    api: CaptureApi,
    /// Per buffer, its planes (one for a single-planar node).
    buffers: Vec<Vec<Mapping>>,
    format: PixelFormat,
    width: u32,
    height: u32,
    /// Bytes per line of each plane, as the driver set them.
    strides: Vec<usize>,
    timeout_ms: i32,
    streaming: bool,
    /// The buffer handed out last, queued again on the next call.
    lent: Option<usize>,
    gathered: Vec<u8>,
}

impl MmapStream {
    /// Requests and maps `count` buffers for frames of `format` at `width`×`height` in planes
    /// of `strides` bytes per line (one plane for a single-planar node, as the driver set
    /// them).
    pub fn new(
        handle: Arc<Handle>,
        api: CaptureApi,
        format: PixelFormat,
        (width, height): (u32, u32),
        strides: Vec<usize>,
        count: u32,
    ) -> io::Result<Self> {
        let plane_count = strides.len();
        let fits = plane_count == 1 || api == CaptureApi::MultiPlanar;
        if !fits || plane_rows(format, width, height, plane_count).is_none() {
            return Err(io::Error::new(
                io::ErrorKind::Unsupported,
                format!("{format} in {plane_count} planes is not supported"),
            ));
        }
        let mut stream = Self {
            handle,
            api,
            buffers: Vec::new(),
            format,
            width,
            height,
            strides,
            timeout_ms: -1,
            streaming: false,
            lent: None,
            gathered: Vec::new(),
        };
        let mut request = stream.request_desc(count);
        // SAFETY: VIDIOC_REQBUFS reads and writes a v4l2_requestbuffers.
        unsafe { ioctl(&stream.handle, vidioc::VIDIOC_REQBUFS, &mut request) }
            .map_err(|e| stream.named("VIDIOC_REQBUFS", e))?;
        // From here on `Drop` unmaps what was mapped (each plane as soon as it is) and frees
        // the buffers.
        let fd = stream.handle.fd();
        for index in 0..request.count {
            let mut planes = [zeroed_plane(); MAX_PLANES];
            let mut buffer = stream.buffer_desc(index, &mut planes);
            // SAFETY: VIDIOC_QUERYBUF reads and writes a v4l2_buffer whose `m.planes` (for
            // the multi-planar type) points at `length` planes, here an array of MAX_PLANES
            // that outlives the call.
            unsafe { ioctl(&stream.handle, vidioc::VIDIOC_QUERYBUF, &mut buffer) }
                .map_err(|e| stream.named("VIDIOC_QUERYBUF", e))?;
            // (offset, length) of each plane.
            let regions: Vec<(u32, usize)> = match stream.api {
                // SAFETY: the union holds `offset` for a memory-mapped single-planar buffer,
                // and each plane's `mem_offset` for a multi-planar one.
                CaptureApi::SinglePlanar => {
                    vec![(unsafe { buffer.m.offset }, buffer.length as usize)]
                }
                CaptureApi::MultiPlanar => planes[..plane_count]
                    .iter()
                    .map(|p| (unsafe { p.m.mem_offset }, p.length as usize))
                    .collect(),
            };
            stream.buffers.push(Vec::with_capacity(plane_count));
            for (offset, len) in regions {
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
                .map_err(|e| named("mmap of a buffer", e))?;
                let start = NonNull::new(start.cast::<u8>())
                    .ok_or_else(|| io::Error::other("mmap of a buffer returned a null address"))?;
                if let Some(mapped) = stream.buffers.last_mut() {
                    mapped.push(Mapping { start, len });
                }
            }
        }
        if stream.buffers.is_empty() {
            return Err(stream.named(
                "VIDIOC_REQBUFS",
                io::Error::other("the driver gave no buffers"),
            ));
        }
        Ok(stream)
    }

    /// How long [`next_frame`](Self::next_frame) waits for a frame before it fails with
    /// `TimedOut`.
    pub fn set_timeout(&mut self, timeout: Duration) {
        self.timeout_ms = timeout.as_millis().min(i32::MAX as u128) as i32;
    }

    fn buffer_type(&self) -> u32 {
        self.api.buffer_type()
    }

    fn named(&self, request: &str, e: io::Error) -> io::Error {
        named_on(self.api, request, e)
    }

    fn request_desc(&self, count: u32) -> v4l2_requestbuffers {
        // SAFETY: all-zero is a valid v4l2_requestbuffers.
        let mut request: v4l2_requestbuffers = unsafe { std::mem::zeroed() };
        request.count = count;
        request.type_ = self.buffer_type();
        request.memory = MEMORY_MMAP;
        request
    }

    fn buffer_desc(&self, index: u32, planes: &mut [v4l2_plane; MAX_PLANES]) -> v4l2_buffer {
        // SAFETY: all-zero is a valid v4l2_buffer (integers, a timeval and unions).
        let mut buffer: v4l2_buffer = unsafe { std::mem::zeroed() };
        buffer.index = index;
        buffer.type_ = self.buffer_type();
        buffer.memory = MEMORY_MMAP;
        if self.api == CaptureApi::MultiPlanar {
            buffer.m.planes = planes.as_mut_ptr();
            buffer.length = self.strides.len() as u32;
        }
        buffer
    }

    fn queue(&mut self, index: usize) -> io::Result<()> {
        let mut planes = [zeroed_plane(); MAX_PLANES];
        let mut buffer = self.buffer_desc(index as u32, &mut planes);
        // SAFETY: VIDIOC_QBUF reads a v4l2_buffer (with its plane array; see `new`).
        unsafe { ioctl(&self.handle, vidioc::VIDIOC_QBUF, &mut buffer) }
            .map_err(|e| self.named("VIDIOC_QBUF", e))
    }

    fn set_streaming(&mut self, on: bool) -> io::Result<()> {
        let (request, name) = if on {
            (vidioc::VIDIOC_STREAMON, "VIDIOC_STREAMON")
        } else {
            (vidioc::VIDIOC_STREAMOFF, "VIDIOC_STREAMOFF")
        };
        let mut kind = self.buffer_type() as libc::c_int;
        // SAFETY: VIDIOC_STREAMON and _STREAMOFF read the buffer type as an int.
        unsafe { ioctl(&self.handle, request, &mut kind) }.map_err(|e| self.named(name, e))?;
        self.streaming = on;
        Ok(())
    }

    /// Waits for a buffer (at most the timeout in all) and dequeues it into `buffer` (and
    /// `planes`).
    fn dequeue(
        &self,
        buffer: &mut v4l2_buffer,
        planes: &mut [v4l2_plane; MAX_PLANES],
    ) -> io::Result<()> {
        let start = Instant::now();
        let timed_out = || {
            self.named(
                "VIDIOC_DQBUF",
                io::Error::new(io::ErrorKind::TimedOut, "no frame within the timeout"),
            )
        };
        loop {
            // What is left of the timeout (-1: none).
            let wait_ms = if self.timeout_ms < 0 {
                -1
            } else {
                let spent = start.elapsed().as_millis().min(i32::MAX as u128) as i32;
                self.timeout_ms.saturating_sub(spent).max(0)
            };
            match self.handle.poll(libc::POLLIN, wait_ms) {
                Ok(0) => return Err(timed_out()),
                Ok(_) => {}
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(named("poll", e)),
            }
            loop {
                *buffer = self.buffer_desc(0, planes);
                // SAFETY: VIDIOC_DQBUF writes a v4l2_buffer (and its plane array; see `new`).
                match unsafe { ioctl(&self.handle, vidioc::VIDIOC_DQBUF, buffer) } {
                    Ok(()) => return Ok(()),
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                    // Woken with no buffer ready: wait again, within the timeout (and not in
                    // a busy loop, should the node keep waking us).
                    Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                        if self.timeout_ms >= 0
                            && start.elapsed() >= Duration::from_millis(self.timeout_ms as u64)
                        {
                            return Err(timed_out());
                        }
                        std::thread::sleep(Duration::from_millis(1));
                        break;
                    }
                    Err(e) => return Err(self.named("VIDIOC_DQBUF", e)),
                }
            }
        }
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
            self.set_streaming(true)?;
        }
        let mut planes = [zeroed_plane(); MAX_PLANES];
        let mut buffer = self.buffer_desc(0, &mut planes);
        self.dequeue(&mut buffer, &mut planes)?;
        let index = buffer.index as usize;
        let Some(mapped) = self.buffers.get(index) else {
            let e = io::Error::new(
                io::ErrorKind::InvalidData,
                format!("buffer {index} of {}", self.buffers.len()),
            );
            return Err(self.named("VIDIOC_DQBUF", e));
        };
        self.lent = Some(index);
        // Each plane's payload, with the bytes between its rows.
        let payload: Vec<PlaneData<'_>> = match self.api {
            CaptureApi::SinglePlanar => {
                let end = (buffer.bytesused as usize).min(mapped[0].len);
                vec![PlaneData {
                    bytes: &mapped[0].bytes()[..end],
                    stride: self.strides[0],
                }]
            }
            CaptureApi::MultiPlanar => (planes.iter().zip(mapped).zip(&self.strides))
                .map(|((plane, mapping), &stride)| {
                    let end = (plane.bytesused as usize).min(mapping.len);
                    let start = (plane.data_offset as usize).min(end);
                    PlaneData {
                        bytes: &mapping.bytes()[start..end],
                        stride,
                    }
                })
                .collect(),
        };
        let mut meta = Metadata {
            bytesused: 0,
            flags: buffer.flags.into(),
            field: buffer.field,
            timestamp: buffer.timestamp.into(),
            sequence: buffer.sequence,
        };
        let data = if meta.flags.contains(v4l::buffer::Flags::ERROR) {
            Err("the driver flagged the buffer as corrupt".to_string())
        } else if let Some(i) = payload.iter().position(|plane| plane.bytes.is_empty()) {
            Err(match self.api {
                CaptureApi::SinglePlanar => "the buffer is empty".to_string(),
                CaptureApi::MultiPlanar => format!("plane {i} of the buffer is empty"),
            })
        } else if let [one] = payload[..] {
            Ok(one.bytes)
        } else {
            gather_planes(
                self.format,
                self.width,
                self.height,
                &payload,
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

impl Drop for MmapStream {
    fn drop(&mut self) {
        let mut problems = Vec::new();
        if self.streaming {
            if let Err(e) = self.set_streaming(false) {
                problems.push(e.to_string());
            }
        }
        for mapping in self.buffers.drain(..).flatten() {
            // SAFETY: a live mapping made in `new`, unmapped once, here.
            if let Err(e) = unsafe { v4l2::munmap(mapping.start.as_ptr().cast(), mapping.len) } {
                problems.push(format!("munmap: {e}"));
            }
        }
        // Count 0 frees the buffers (refused while the queue still streams).
        let mut request = self.request_desc(0);
        // SAFETY: VIDIOC_REQBUFS reads and writes a v4l2_requestbuffers.
        if let Err(e) = unsafe { ioctl(&self.handle, vidioc::VIDIOC_REQBUFS, &mut request) } {
            problems.push(self.named("VIDIOC_REQBUFS 0", e).to_string());
        }
        if !problems.is_empty() {
            tracing::warn!(
                "closing the camera stream (fd {}): {} (device gone?)",
                self.handle.fd(),
                problems.join("; ")
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::pixel_format::PlanarYuv;

    /// On a file that is no V4L2 node the stream fails at its first request, naming it (no
    /// panic, nothing mapped); a plane count the API or the format does not allow is refused
    /// before any request. tests/fake_v4l2.rs streams from a fake driver.
    #[test]
    fn a_stream_on_no_v4l2_node_or_of_impossible_planes_is_an_error() {
        let device = v4l::Device::with_path("/dev/null").unwrap();
        let nv12 = PixelFormat::PlanarYuv(PlanarYuv::Nv12);
        let open = |api, format, strides: Vec<usize>| {
            MmapStream::new(device.handle(), api, format, (640, 480), strides, 4)
                .err()
                .unwrap()
                .to_string()
        };
        let e = open(CaptureApi::MultiPlanar, nv12, vec![640, 640]);
        assert!(e.starts_with("VIDIOC_REQBUFS (multi-planar): "), "{e}");
        let e = open(CaptureApi::SinglePlanar, nv12, vec![640]);
        assert!(e.starts_with("VIDIOC_REQBUFS: "), "{e}");
        let grey = PixelFormat::Grey { bits: 8 };
        let e = open(CaptureApi::MultiPlanar, grey, vec![640, 640]);
        assert!(e.contains("in 2 planes is not supported"), "{e}");
        let e = open(CaptureApi::SinglePlanar, nv12, vec![640, 640]);
        assert!(e.contains("in 2 planes is not supported"), "{e}");
    }
}
