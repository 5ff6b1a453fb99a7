//! envlight's camera code against a fake V4L2 driver in user space: its stream of single- and
//! multi-planar buffers (src/capture/v4l2_stream.rs), its multi-planar format calls
//! (src/capture/v4l2_mplane.rs) and the `v4l` crate's capability, format and control calls run
//! through real `ioctl`, `mmap` and `poll` system calls, with no camera and no kernel module.
//!
//! How the fake works:
//! 1. the "device" is a regular temporary file: `open`, `poll` (a file is always readable) and
//!    the `mmap` of buffers at the offsets the fake hands out are the kernel's own;
//! 2. the test thread installs a seccomp filter that turns every `ioctl` of V4L2's type `'V'`
//!    into a user notification (`SECCOMP_RET_USER_NOTIF`, Linux 5.0 and later); the filter is
//!    the thread's own, so other tests are not affected;
//! 3. a driver thread, started before the filter and so outside it, receives each
//!    notification, reads and writes the caller's structure as a driver does (with
//!    `process_vm_readv` / `process_vm_writev`: the caller, blocked in the call, is a thread of
//!    this process or of a child that inherited the filter, such as the `envlight` binary),
//!    and answers with a return value or an errno;
//! 4. at `VIDIOC_DQBUF` the driver writes the next frame into the buffer's planes in the file,
//!    which the caller's mapping shows.
//!
//! The tests stream the same frames through both APIs and compare the radiance envlight makes
//! of them, bit for bit: NV12 in one buffer against NM12 in two planes (padded rows, a
//! payload after a `data_offset`), YU12 against YM12 in three, and CSI-2 packed raw in one
//! plane of a multi-planar node; with a frame the driver flags corrupt and one whose chroma
//! plane comes short, both skipped. Behind the exposure and gain controls the fake has a
//! sensor, for auto exposure and bracketing; it can lose the device mid-stream; and
//! `envlight decompose --device` runs against it end to end.

mod common;

use envlight::capture::pixel_format::{PackedYuv, PixelFormat};
use envlight::capture::v4l2::{CameraSettings, V4l2Source};
use envlight::capture::FrameSource;
use envlight::frame::HdrFrame;
use std::collections::VecDeque;
use std::fs::File;
use std::os::raw::c_void;
use std::os::unix::fs::FileExt;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use v4l::v4l2::vidioc;
use v4l::v4l_sys::{
    v4l2_buffer, v4l2_capability, v4l2_ext_control, v4l2_ext_controls, v4l2_fmtdesc, v4l2_format,
    v4l2_plane, v4l2_query_ext_ctrl, v4l2_requestbuffers, v4l2_streamparm,
};

// The kernel's constants, written out here rather than taken from envlight's modules, so that
// a wrong one there disagrees with the fake instead of agreeing with it.
const CAPTURE: u32 = 1;
const CAPTURE_MPLANE: u32 = 9;
const CAP_VIDEO_CAPTURE: u32 = 0x1;
const CAP_VIDEO_CAPTURE_MPLANE: u32 = 0x1000;
const CAP_STREAMING: u32 = 0x0400_0000;
const CAP_DEVICE_CAPS: u32 = 0x8000_0000;
const BUF_FLAG_ERROR: u32 = 0x40;
const PAGE: usize = 4096;

/// One plane of image content: rows of bytes, the same whichever API carries them.
#[derive(Clone, Debug)]
struct ContentPlane {
    row_bytes: usize,
    rows: usize,
}

/// How the fake carries a frame.
#[derive(Clone, Debug)]
enum Carriage {
    /// One buffer; the content planes one after another, each at its stride.
    Single {
        fourcc: [u8; 4],
        strides: Vec<usize>,
    },
    /// One plane per content plane (or all content in one plane), each with its stride and
    /// a header of `data_offset` bytes before the payload.
    Multi {
        fourcc: [u8; 4],
        strides: Vec<usize>,
        data_offsets: Vec<usize>,
    },
}

/// What the fake camera is.
#[derive(Clone, Debug)]
struct Camera {
    width: u32,
    height: u32,
    content: Vec<ContentPlane>,
    carriage: Carriage,
    /// Sequence numbers the driver flags `V4L2_BUF_FLAG_ERROR`.
    corrupt: Vec<u32>,
    /// Sequence numbers whose last plane comes with half its payload.
    short: Vec<u32>,
    /// The controls the driver offers (exposure, gain).
    controls: Vec<FakeControl>,
    /// With a sensor, frames are its radiance seen through the exposure and gain in force
    /// (8-bit grey in one plane) instead of the test pattern.
    sensor: Option<Sensor>,
    /// From this frame on the device is gone: `VIDIOC_DQBUF` fails with ENODEV, and stopping
    /// the stream with EIO (as after an unplug) …
    lost_at: Option<u32>,
    /// … and this many attempts to open it again fail (`VIDIOC_QUERYCAP`: ENODEV) before it
    /// is back.
    unplugged_opens: u32,
    /// With payloads, frame `seq` is payload `seq` mod their count as it is, in one buffer of
    /// the largest payload's size (`bytesperline` 0): compressed frames of varying length, or
    /// packed rows.
    payloads: Vec<Vec<u8>>,
    /// A frame is ready this long after the one before (`VIDIOC_DQBUF` waits), as a camera's
    /// frame rate; none: at once.
    frame_interval: Option<Duration>,
    /// The first attempt to dequeue frame `seq` fails with `errno` (EINTR: a signal; EAGAIN:
    /// woken with no buffer ready), once each.
    dequeue_hiccups: Vec<(u32, i32)>,
    /// From this frame on no frame is ready any more: `VIDIOC_DQBUF` fails with EAGAIN.
    stalled_from: Option<u32>,
    /// The driver sets this pixel format whatever is asked for (as drivers substitute one
    /// they have).
    substitute: Option<[u8; 4]>,
    /// The card name `VIDIOC_QUERYCAP` gives (at most 31 bytes).
    card: Vec<u8>,
    /// The format's description `VIDIOC_ENUM_FMT` gives (at most 31 bytes).
    format_description: Vec<u8>,
}

/// A control of the fake driver.
#[derive(Clone, Debug)]
struct FakeControl {
    id: u32,
    /// `V4L2_CTRL_TYPE_INTEGER` (1) or `_MENU` (3).
    kind: u32,
    name: &'static str,
    minimum: i64,
    maximum: i64,
    default: i64,
}

const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
const CID_GAIN: u32 = 0x0098_0913;

/// Exposure (100 µs units, 1 ms default), auto exposure (a menu: 1 manual, 3 aperture
/// priority, the default) and gain (16 = unity, the default), as a UVC camera has them.
fn exposure_controls() -> Vec<FakeControl> {
    vec![
        FakeControl {
            id: CID_GAIN,
            kind: 1,
            name: "Gain",
            minimum: 1,
            maximum: 255,
            default: 16,
        },
        FakeControl {
            id: CID_EXPOSURE_AUTO,
            kind: 3,
            name: "Auto Exposure",
            minimum: 0,
            maximum: 3,
            default: 3,
        },
        FakeControl {
            id: CID_EXPOSURE_ABSOLUTE,
            kind: 1,
            name: "Exposure Time, Absolute",
            minimum: 1,
            maximum: 10_000,
            default: 10,
        },
        // A compound control of a type newer than the `v4l` crate
        // (`V4L2_CTRL_TYPE_RECT`, 0x0107), as UVC cameras have since Linux 6.15 (2025)
        // (`V4L2_CID_UVC_REGION_OF_INTEREST_RECT`).
        FakeControl {
            id: 0x0a04_6901,
            kind: 0x0107,
            name: "Region Of Interest Rectangle",
            minimum: 0,
            maximum: 0,
            default: 0,
        },
    ]
}

/// A scene in front of the fake camera.
#[derive(Clone, Debug)]
struct Sensor {
    /// Per pixel, the code value a 1 s exposure at unity gain would give (before clipping).
    radiance: Vec<f64>,
    /// Frames between setting a control and the first frame taken with it.
    lag: u32,
    /// The camera's own auto exposure sets the exposure control to this value (100 µs units)
    /// at this frame, while the auto-exposure control is not at manual (1).
    auto_exposure: Option<(u32, i64)>,
}

impl Camera {
    fn new(width: u32, height: u32, content: Vec<ContentPlane>, carriage: Carriage) -> Self {
        Camera {
            width,
            height,
            content,
            carriage,
            corrupt: Vec::new(),
            short: Vec::new(),
            controls: Vec::new(),
            sensor: None,
            lost_at: None,
            unplugged_opens: 0,
            payloads: Vec::new(),
            frame_interval: None,
            dequeue_hiccups: Vec::new(),
            stalled_from: None,
            substitute: None,
            card: b"Fake camera".to_vec(),
            format_description: b"fake format".to_vec(),
        }
    }

    /// An 8-bit grey camera that sees `sensor` through its exposure controls.
    fn grey(width: u32, height: u32, sensor: Sensor) -> Self {
        let content = vec![ContentPlane {
            row_bytes: width as usize,
            rows: height as usize,
        }];
        let carriage = Carriage::Single {
            fourcc: *b"GREY",
            strides: vec![width as usize],
        };
        Camera {
            controls: exposure_controls(),
            sensor: Some(sensor),
            ..Camera::new(width, height, content, carriage)
        }
    }
}

impl Camera {
    fn multi(&self) -> bool {
        matches!(self.carriage, Carriage::Multi { .. })
    }

    fn fourcc(&self) -> [u8; 4] {
        match &self.carriage {
            Carriage::Single { fourcc, .. } | Carriage::Multi { fourcc, .. } => *fourcc,
        }
    }

    /// The driver's planes: (bytes per line, payload bytes, data offset).
    fn planes(&self) -> Vec<(usize, usize, usize)> {
        if let Some(largest) = self.payloads.iter().map(Vec::len).max() {
            return vec![(0, largest, 0)];
        }
        let span = |c: &ContentPlane, stride: usize| (c.rows - 1) * stride + c.row_bytes;
        match &self.carriage {
            Carriage::Single { strides, .. } => {
                let last = self.content.len() - 1;
                let bytes = self
                    .content
                    .iter()
                    .zip(strides)
                    .enumerate()
                    .map(|(i, (c, &s))| if i == last { span(c, s) } else { c.rows * s })
                    .sum();
                vec![(strides[0], bytes, 0)]
            }
            Carriage::Multi {
                strides,
                data_offsets,
                ..
            } if strides.len() == 1 => {
                // Everything in one plane, packed as the one-buffer layout.
                let bytes = self.content.iter().map(|c| c.rows * strides[0]).sum();
                vec![(strides[0], bytes, data_offsets[0])]
            }
            Carriage::Multi {
                strides,
                data_offsets,
                ..
            } => self
                .content
                .iter()
                .zip(strides)
                .zip(data_offsets)
                .map(|((c, &s), &o)| (s, span(c, s), o))
                .collect(),
        }
    }

    /// Byte `x` of row `row` of content plane `p` in frame `seq`: varied, and different from
    /// frame to frame.
    fn byte(seq: u32, p: usize, row: usize, x: usize) -> u8 {
        ((x * 7 + row * 13 + p * 61 + seq as usize * 29) % 239 + 8) as u8
    }

    /// Frame `seq` as the driver's planes hold it (headers and padding filled with 0xEE).
    fn frame(&self, seq: u32) -> Vec<Vec<u8>> {
        if !self.payloads.is_empty() {
            return vec![self.payloads[seq as usize % self.payloads.len()].clone()];
        }
        let rows_into = |out: &mut Vec<u8>, p: usize, c: &ContentPlane, stride: usize| {
            for row in 0..c.rows {
                for x in 0..stride {
                    out.push(if x < c.row_bytes {
                        Self::byte(seq, p, row, x)
                    } else {
                        0xEE
                    });
                }
            }
        };
        let planes = self.planes();
        match &self.carriage {
            Carriage::Single { strides, .. } => {
                let mut out = Vec::new();
                for (p, (c, &s)) in self.content.iter().zip(strides).enumerate() {
                    rows_into(&mut out, p, c, s);
                }
                out.truncate(planes[0].1);
                vec![out]
            }
            Carriage::Multi {
                strides,
                data_offsets,
                ..
            } if strides.len() == 1 => {
                let mut out = vec![0xEE; data_offsets[0]];
                for (p, c) in self.content.iter().enumerate() {
                    rows_into(&mut out, p, c, strides[0]);
                }
                vec![out]
            }
            Carriage::Multi {
                strides,
                data_offsets,
                ..
            } => self
                .content
                .iter()
                .zip(strides)
                .zip(data_offsets)
                .enumerate()
                .map(|(p, ((c, &s), &o))| {
                    let mut out = vec![0xEE; o];
                    rows_into(&mut out, p, c, s);
                    out.truncate(o + planes[p].1);
                    out
                })
                .collect(),
        }
    }
}

/// The memory of the thread that made a call: of this process, or of a child process that
/// inherited the filter (read and written with `process_vm_readv` / `process_vm_writev`).
struct Caller {
    pid: libc::pid_t,
}

impl Caller {
    fn transfer(&self, local: *mut c_void, addr: u64, len: usize, write: bool) -> Result<(), i32> {
        let local = libc::iovec {
            iov_base: local,
            iov_len: len,
        };
        let remote = libc::iovec {
            iov_base: addr as *mut c_void,
            iov_len: len,
        };
        // SAFETY: `local` is `len` bytes of ours; the kernel checks the caller's range.
        let done = unsafe {
            if write {
                libc::process_vm_writev(self.pid, &local, 1, &remote, 1, 0)
            } else {
                libc::process_vm_readv(self.pid, &local, 1, &remote, 1, 0)
            }
        };
        if done == len as isize {
            Ok(())
        } else {
            Err(libc::EFAULT)
        }
    }

    /// `n` values of `T` at `addr` (kernel structures: plain data).
    fn read_array<T: Copy>(&self, addr: u64, n: usize) -> Result<Vec<T>, i32> {
        let mut out: Vec<T> = Vec::with_capacity(n);
        self.transfer(
            out.as_mut_ptr().cast(),
            addr,
            n * std::mem::size_of::<T>(),
            false,
        )?;
        // SAFETY: the kernel structures read are plain data, all `n` filled.
        unsafe { out.set_len(n) };
        Ok(out)
    }

    fn read<T: Copy>(&self, addr: u64) -> Result<T, i32> {
        Ok(self.read_array(addr, 1)?[0])
    }

    fn write_array<T: Copy>(&self, addr: u64, values: &[T]) -> Result<(), i32> {
        let len = std::mem::size_of_val(values);
        self.transfer(values.as_ptr() as *mut c_void, addr, len, true)
    }

    fn write<T: Copy>(&self, addr: u64, value: &T) -> Result<(), i32> {
        self.write_array(addr, std::slice::from_ref(value))
    }
}

/// The fake driver's state.
struct Driver {
    camera: Camera,
    file: File,
    /// Per buffer, per plane: its offset in the file and its length.
    buffers: Vec<Vec<(usize, usize)>>,
    queued: VecDeque<u32>,
    streaming: bool,
    sequence: u32,
    /// The requests it answered, by name, for the tests to check the order of calls.
    log: Arc<Mutex<Vec<String>>>,
    /// The controls' values as set (and read back).
    values: Vec<(u32, i64)>,
    /// Values set, with the first frame that is taken with them.
    pending: Vec<(u32, u32, i64)>,
    /// The values the sensor works with now.
    applied: Vec<(u32, i64)>,
    /// See [`FakeDevice::present`].
    present: Arc<AtomicBool>,
    /// With a frame interval, when the next frame is ready.
    next_frame_at: Option<std::time::Instant>,
}

fn value_of(values: &[(u32, i64)], id: u32) -> Option<i64> {
    values.iter().find(|(i, _)| *i == id).map(|(_, v)| *v)
}

fn set_value(values: &mut Vec<(u32, i64)>, id: u32, value: i64) {
    values.retain(|(i, _)| *i != id);
    values.push((id, value));
}

fn copy_name(dst: &mut [u8], name: &str) {
    dst[..name.len()].copy_from_slice(name.as_bytes());
}

impl Driver {
    fn buffer_type(&self) -> u32 {
        if self.camera.multi() {
            CAPTURE_MPLANE
        } else {
            CAPTURE
        }
    }

    fn note(&self, what: String) {
        self.log.lock().unwrap().push(what);
    }

    /// Answers one ioctl of `caller`: `Ok(())` or an errno.
    fn handle(&mut self, caller: &Caller, request: u64, arg: u64) -> Result<(), i32> {
        // The request type is 64 bits wide on 64-bit targets, 32 on others.
        #[allow(clippy::unnecessary_cast)]
        let is = |r: vidioc::_IOC_TYPE| request & 0xffff_ffff == (r as u64) & 0xffff_ffff;
        let (w, h) = (self.camera.width, self.camera.height);
        let fourcc = u32::from_le_bytes(self.camera.fourcc());
        if is(vidioc::VIDIOC_QUERYCAP) {
            if !self.present.load(Ordering::SeqCst) {
                self.note("QUERYCAP failed: ENODEV".into());
                return Err(libc::ENODEV);
            }
            if self.camera.lost_at.is_some_and(|at| self.sequence >= at) {
                if self.camera.unplugged_opens > 0 {
                    self.camera.unplugged_opens -= 1;
                    self.note("QUERYCAP failed: ENODEV".into());
                    return Err(libc::ENODEV);
                }
                // Plugged in again.
                self.camera.lost_at = None;
                self.streaming = false;
                self.queued.clear();
                self.note("back".into());
            }
            let mut caps: v4l2_capability = caller.read(arg)?;
            copy_name(&mut caps.driver, "fakecam");
            caps.card[..self.camera.card.len()].copy_from_slice(&self.camera.card);
            copy_name(&mut caps.bus_info, "platform:fake");
            caps.device_caps = CAP_STREAMING
                | if self.camera.multi() {
                    CAP_VIDEO_CAPTURE_MPLANE
                } else {
                    CAP_VIDEO_CAPTURE
                };
            caps.capabilities = caps.device_caps | CAP_DEVICE_CAPS;
            self.note("QUERYCAP".into());
            caller.write(arg, &caps)
        } else if is(vidioc::VIDIOC_ENUM_FMT) {
            let mut desc: v4l2_fmtdesc = caller.read(arg)?;
            if desc.type_ != self.buffer_type() || desc.index > 0 {
                return Err(libc::EINVAL);
            }
            desc.pixelformat = fourcc;
            let text = &self.camera.format_description;
            desc.description[..text.len()].copy_from_slice(text);
            self.note(format!("ENUM_FMT type {}", desc.type_));
            caller.write(arg, &desc)
        } else if is(vidioc::VIDIOC_G_FMT) || is(vidioc::VIDIOC_S_FMT) {
            let mut f: v4l2_format = caller.read(arg)?;
            if f.type_ != self.buffer_type() {
                return Err(libc::EINVAL);
            }
            let set_fourcc = self.camera.substitute.map_or(fourcc, u32::from_le_bytes);
            let planes = self.camera.planes();
            // SAFETY: the union member of the buffer type checked above.
            unsafe {
                if self.camera.multi() {
                    let pix = &mut f.fmt.pix_mp;
                    pix.width = w;
                    pix.height = h;
                    pix.pixelformat = set_fourcc;
                    pix.colorspace = 3; // V4L2_COLORSPACE_REC709
                    pix.num_planes = planes.len() as u8;
                    for (slot, &(stride, bytes, offset)) in pix.plane_fmt.iter_mut().zip(&planes) {
                        slot.bytesperline = stride as u32;
                        slot.sizeimage = (bytes + offset) as u32;
                    }
                } else {
                    let pix = &mut f.fmt.pix;
                    pix.width = w;
                    pix.height = h;
                    pix.pixelformat = set_fourcc;
                    pix.bytesperline = planes[0].0 as u32;
                    pix.sizeimage = planes[0].1 as u32;
                    pix.colorspace = 3;
                }
            }
            let name = if is(vidioc::VIDIOC_S_FMT) {
                "S_FMT"
            } else {
                "G_FMT"
            };
            self.note(name.into());
            caller.write(arg, &f)
        } else if is(vidioc::VIDIOC_G_PARM) || is(vidioc::VIDIOC_S_PARM) {
            let mut parm: v4l2_streamparm = caller.read(arg)?;
            if parm.type_ != self.buffer_type() {
                return Err(libc::EINVAL);
            }
            // SAFETY: a capture buffer type: the union holds `capture`.
            let capture = unsafe { &mut parm.parm.capture };
            capture.capability = 0x1000; // V4L2_CAP_TIMEPERFRAME
            if is(vidioc::VIDIOC_S_PARM) {
                let t = capture.timeperframe;
                self.note(format!("S_PARM {}/{}", t.numerator, t.denominator));
            }
            caller.write(arg, &parm)
        } else if is(vidioc::VIDIOC_REQBUFS) {
            let mut req: v4l2_requestbuffers = caller.read(arg)?;
            if req.type_ != self.buffer_type() || req.memory != 1 {
                return Err(libc::EINVAL);
            }
            if self.streaming {
                // As videobuf2: the buffers of a streaming queue cannot be changed.
                self.note("REQBUFS failed: EBUSY".into());
                return Err(libc::EBUSY);
            }
            self.note(format!("REQBUFS {}", req.count));
            self.buffers.clear();
            self.queued.clear();
            let planes = self.camera.planes();
            let mut at = 0;
            for _ in 0..req.count.min(8) {
                let mut buffer = Vec::new();
                for &(_, bytes, offset) in &planes {
                    let len = bytes + offset;
                    buffer.push((at, len));
                    at += len.div_ceil(PAGE) * PAGE;
                }
                self.buffers.push(buffer);
            }
            self.file.set_len(at as u64).map_err(|_| libc::EIO)?;
            req.count = self.buffers.len() as u32;
            caller.write(arg, &req)
        } else if is(vidioc::VIDIOC_QUERYBUF) || is(vidioc::VIDIOC_QBUF) || is(vidioc::VIDIOC_DQBUF)
        {
            let mut buf: v4l2_buffer = caller.read(arg)?;
            if buf.type_ != self.buffer_type() || buf.memory != 1 {
                return Err(libc::EINVAL);
            }
            if self.camera.multi() && (buf.length as usize) < self.camera.planes().len() {
                return Err(libc::EINVAL);
            }
            if is(vidioc::VIDIOC_DQBUF) {
                self.dequeue(caller, &mut buf)?;
                return caller.write(arg, &buf);
            }
            let index = buf.index;
            let Some(planes) = self.buffers.get(index as usize) else {
                return Err(libc::EINVAL);
            };
            if is(vidioc::VIDIOC_QBUF) {
                self.queued.push_back(index);
                return Ok(());
            }
            if self.camera.multi() {
                // SAFETY: a multi-planar buffer: the union holds the plane array's address.
                let array = unsafe { buf.m.planes } as u64;
                let mut out: Vec<v4l2_plane> = caller.read_array(array, planes.len())?;
                for (slot, &(offset, len)) in out.iter_mut().zip(planes) {
                    slot.length = len as u32;
                    slot.m.mem_offset = offset as u32;
                }
                caller.write_array(array, &out)?;
            } else {
                buf.m.offset = planes[0].0 as u32;
                buf.length = planes[0].1 as u32;
            }
            caller.write(arg, &buf)
        } else if is(vidioc::VIDIOC_STREAMON) || is(vidioc::VIDIOC_STREAMOFF) {
            if caller.read::<i32>(arg)? as u32 != self.buffer_type() {
                return Err(libc::EINVAL);
            }
            if self.camera.lost_at.is_some_and(|at| self.sequence >= at) {
                self.note("STREAMOFF failed: EIO".into());
                return Err(libc::EIO);
            }
            self.streaming = is(vidioc::VIDIOC_STREAMON);
            let name = if self.streaming {
                "STREAMON"
            } else {
                "STREAMOFF"
            };
            self.note(name.into());
            Ok(())
        } else if is(vidioc::VIDIOC_QUERY_EXT_CTRL) {
            let mut query: v4l2_query_ext_ctrl = caller.read(arg)?;
            let next = query.id & 0x8000_0000 != 0;
            let id = query.id & 0x0fff_ffff;
            let mut sorted = self.camera.controls.clone();
            sorted.sort_by_key(|c| c.id);
            let found = if next {
                sorted.into_iter().find(|c| c.id > id)
            } else {
                sorted.into_iter().find(|c| c.id == id)
            };
            let Some(c) = found else {
                return Err(libc::EINVAL);
            };
            // SAFETY: all-zero is a valid v4l2_query_ext_ctrl.
            query = unsafe { std::mem::zeroed() };
            query.id = c.id;
            query.type_ = c.kind;
            for (dst, src) in query.name.iter_mut().zip(c.name.bytes()) {
                *dst = src as std::os::raw::c_char;
            }
            query.minimum = c.minimum;
            query.maximum = c.maximum;
            query.step = 1;
            query.default_value = c.default;
            query.elem_size = 4;
            query.elems = 1;
            caller.write(arg, &query)
        } else if is(vidioc::VIDIOC_G_EXT_CTRLS) || is(vidioc::VIDIOC_S_EXT_CTRLS) {
            let list: v4l2_ext_controls = caller.read(arg)?;
            let array = list.controls as u64;
            let mut controls: Vec<v4l2_ext_control> =
                caller.read_array(array, list.count as usize)?;
            for control in &mut controls {
                let Some(c) = self.camera.controls.iter().find(|c| c.id == control.id) else {
                    return Err(libc::EINVAL);
                };
                if is(vidioc::VIDIOC_G_EXT_CTRLS) {
                    let value = value_of(&self.values, c.id).unwrap_or(c.default);
                    control.__bindgen_anon_1.value = value as i32;
                } else {
                    // SAFETY: an integer or menu control carries its value in `value`.
                    let value = i64::from(unsafe { control.__bindgen_anon_1.value });
                    if !(c.minimum..=c.maximum).contains(&value) {
                        return Err(libc::ERANGE);
                    }
                    set_value(&mut self.values, c.id, value);
                    let lag = self.camera.sensor.as_ref().map_or(0, |s| s.lag);
                    self.pending.push((self.sequence + lag, c.id, value));
                    self.note(format!(
                        "S_CTRL {} {value} at frame {}",
                        c.name, self.sequence
                    ));
                }
            }
            caller.write_array(array, &controls)
        } else {
            // Everything else (menus, selections, …): not implemented, as a driver without
            // them.
            Err(libc::EINVAL)
        }
    }

    /// Frame `seq` of the sensor, in 8-bit grey codes, with the controls in force.
    fn sensor_frame(&mut self, seq: u32, sensor: &Sensor) -> Vec<u8> {
        if let Some((at, value)) = sensor.auto_exposure {
            let auto = value_of(&self.values, CID_EXPOSURE_AUTO).unwrap_or(3) != 1;
            if seq == at && auto {
                set_value(&mut self.values, CID_EXPOSURE_ABSOLUTE, value);
                self.pending.push((seq, CID_EXPOSURE_ABSOLUTE, value));
            }
        }
        for &(from, id, value) in &self.pending {
            if from <= seq {
                set_value(&mut self.applied, id, value);
            }
        }
        self.pending.retain(|&(from, _, _)| from > seq);
        let control = |id| {
            let default = self
                .camera
                .controls
                .iter()
                .find(|c| c.id == id)
                .map(|c| c.default);
            value_of(&self.applied, id).or(default).unwrap_or(1) as f64
        };
        let seconds = control(CID_EXPOSURE_ABSOLUTE) * 1e-4;
        let gain = control(CID_GAIN) / 16.0;
        self.note(format!("frame {seq} taken at {seconds} s, gain {gain}"));
        sensor
            .radiance
            .iter()
            .map(|l| (l * seconds * gain).round().clamp(0.0, 255.0) as u8)
            .collect()
    }

    /// Fills the next frame into the first queued buffer and describes it in `buf` (and the
    /// caller's plane array).
    fn dequeue(&mut self, caller: &Caller, buf: &mut v4l2_buffer) -> Result<(), i32> {
        if !self.streaming {
            return Err(libc::EINVAL);
        }
        if self.camera.lost_at.is_some_and(|at| self.sequence >= at)
            || !self.present.load(Ordering::SeqCst)
        {
            return Err(libc::ENODEV);
        }
        if self
            .camera
            .stalled_from
            .is_some_and(|at| self.sequence >= at)
        {
            return Err(libc::EAGAIN);
        }
        let hiccup =
            (self.camera.dequeue_hiccups.iter()).position(|&(seq, _)| seq == self.sequence);
        if let Some(i) = hiccup {
            let (seq, errno) = self.camera.dequeue_hiccups.remove(i);
            self.note(format!("DQBUF {seq} failed once: errno {errno}"));
            return Err(errno);
        }
        if let Some(interval) = self.camera.frame_interval {
            let now = std::time::Instant::now();
            let at = self.next_frame_at.unwrap_or(now).max(now);
            std::thread::sleep(at - now);
            self.next_frame_at = Some(at + interval);
        }
        let Some(index) = self.queued.pop_front() else {
            return Err(libc::EAGAIN);
        };
        let seq = self.sequence;
        self.sequence += 1;
        let frame = match self.camera.sensor.clone() {
            Some(sensor) => vec![self.sensor_frame(seq, &sensor)],
            None => self.camera.frame(seq),
        };
        let planes = &self.buffers[index as usize];
        let mut used: Vec<usize> = frame.iter().map(Vec::len).collect();
        if self.camera.short.contains(&seq) {
            let last = used.len() - 1;
            let header = self.camera.planes()[last].2;
            used[last] = header + (used[last] - header) / 2;
        }
        for (bytes, &(offset, _)) in frame.iter().zip(planes) {
            self.file
                .write_at(bytes, offset as u64)
                .map_err(|_| libc::EIO)?;
        }
        buf.index = index;
        buf.sequence = seq;
        buf.flags = if self.camera.corrupt.contains(&seq) {
            BUF_FLAG_ERROR
        } else {
            0
        };
        buf.timestamp.tv_sec = 1000 + (seq / 30) as libc::time_t;
        buf.timestamp.tv_usec = (seq % 30 * 33_333) as libc::suseconds_t;
        if self.camera.multi() {
            let header: Vec<usize> = self.camera.planes().iter().map(|p| p.2).collect();
            // SAFETY: a multi-planar buffer: the union holds the plane array's address.
            let array = unsafe { buf.m.planes } as u64;
            let mut out: Vec<v4l2_plane> = caller.read_array(array, used.len())?;
            for ((slot, &n), &o) in out.iter_mut().zip(&used).zip(&header) {
                slot.bytesused = n as u32;
                slot.data_offset = o as u32;
            }
            caller.write_array(array, &out)?;
        } else {
            buf.bytesused = used[0] as u32;
        }
        Ok(())
    }
}

/// The seccomp filter: user notification for `ioctl(_, request of type 'V', _)`.
fn v4l2_ioctl_filter() -> Vec<libc::sock_filter> {
    let stmt = |code: u32, k: u32| libc::sock_filter {
        code: code as u16,
        jt: 0,
        jf: 0,
        k,
    };
    let jump = |code: u32, k: u32, jt: u8, jf: u8| libc::sock_filter {
        code: code as u16,
        jt,
        jf,
        k,
    };
    let (ld, jeq, ret, and) = (
        libc::BPF_LD | libc::BPF_W | libc::BPF_ABS,
        libc::BPF_JMP | libc::BPF_JEQ | libc::BPF_K,
        libc::BPF_RET | libc::BPF_K,
        libc::BPF_ALU | libc::BPF_AND | libc::BPF_K,
    );
    // seccomp_data: nr at 0, arch at 4, ip at 8, args at 16 (u64 each).
    let request_low = if cfg!(target_endian = "little") {
        24
    } else {
        28
    };
    vec![
        stmt(ld, 0),
        jump(jeq, libc::SYS_ioctl as u32, 0, 4),
        stmt(ld, request_low),
        stmt(and, 0xff00),
        jump(jeq, u32::from(b'V') << 8, 0, 1),
        stmt(ret, libc::SECCOMP_RET_USER_NOTIF),
        stmt(ret, libc::SECCOMP_RET_ALLOW),
    ]
}

/// A running fake driver; its V4L2 calls are those of the thread that made it.
struct FakeDevice {
    path: tempfile::TempPath,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
    log: Arc<Mutex<Vec<String>>>,
    /// Cleared, the camera is unplugged (`VIDIOC_DQBUF` and `VIDIOC_QUERYCAP` fail with
    /// ENODEV) until it is set again.
    present: Arc<AtomicBool>,
}

impl FakeDevice {
    /// Starts the driver thread, then puts the calling thread under the filter.
    fn start(camera: Camera) -> FakeDevice {
        let file = tempfile::NamedTempFile::new().unwrap();
        let (file, path) = file.into_parts();
        let log = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let present = Arc::new(AtomicBool::new(true));
        let (send_fd, receive_fd) = std::sync::mpsc::sync_channel::<i32>(1);
        let mut driver = Driver {
            camera,
            file,
            buffers: Vec::new(),
            queued: VecDeque::new(),
            streaming: false,
            sequence: 0,
            log: log.clone(),
            values: Vec::new(),
            pending: Vec::new(),
            applied: Vec::new(),
            present: present.clone(),
            next_frame_at: None,
        };
        let stopping = stop.clone();
        let thread = std::thread::Builder::new()
            .name("fake-v4l2".into())
            .spawn(move || {
                let listener = receive_fd.recv().unwrap();
                serve(listener, &mut driver, &stopping);
                unsafe { libc::close(listener) };
            })
            .unwrap();
        // SAFETY: plain system calls with valid arguments; the filter applies to this thread.
        let listener = unsafe {
            assert_eq!(libc::prctl(libc::PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0), 0);
            let mut filter = v4l2_ioctl_filter();
            let program = libc::sock_fprog {
                len: filter.len() as u16,
                filter: filter.as_mut_ptr(),
            };
            libc::syscall(
                libc::SYS_seccomp,
                libc::SECCOMP_SET_MODE_FILTER,
                libc::SECCOMP_FILTER_FLAG_NEW_LISTENER,
                &program as *const libc::sock_fprog,
            ) as i32
        };
        assert!(
            listener >= 0,
            "seccomp user notification (Linux 5.0+) is needed for the fake V4L2 driver: {}",
            std::io::Error::last_os_error()
        );
        send_fd.send(listener).unwrap();
        FakeDevice {
            path,
            stop,
            thread: Some(thread),
            log,
            present,
        }
    }

    fn settings(&self, format: PixelFormat, width: u32, height: u32) -> CameraSettings {
        CameraSettings {
            device: self.path.display().to_string(),
            formats: vec![format],
            width,
            height,
            fps: Some(30.0),
            timeout: Duration::from_secs(5),
            ..Default::default()
        }
    }

    /// Stops the driver; its log.
    fn finish(mut self) -> Vec<String> {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().unwrap();
        }
        self.log.lock().unwrap().clone()
    }
}

impl Drop for FakeDevice {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The driver thread: answers notifications until told to stop.
fn serve(listener: i32, driver: &mut Driver, stop: &AtomicBool) {
    while !stop.load(Ordering::Relaxed) {
        let mut poll = libc::pollfd {
            fd: listener,
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd.
        if unsafe { libc::poll(&mut poll, 1, 20) } <= 0 || poll.revents & libc::POLLIN == 0 {
            continue;
        }
        // SAFETY: all-zero is a valid seccomp_notif, which NOTIF_RECV fills.
        let mut notification: libc::seccomp_notif = unsafe { std::mem::zeroed() };
        if unsafe { libc::ioctl(listener, libc::SECCOMP_IOCTL_NOTIF_RECV, &mut notification) } != 0
        {
            continue;
        }
        let [_, request, arg, ..] = notification.data.args;
        let caller = Caller {
            pid: notification.pid as libc::pid_t,
        };
        let result = driver.handle(&caller, request, arg);
        let mut response = libc::seccomp_notif_resp {
            id: notification.id,
            val: 0,
            error: 0,
            flags: 0,
        };
        if let Err(errno) = result {
            response.val = -1;
            response.error = -errno;
        }
        // SAFETY: a filled response for the notification just received.
        unsafe { libc::ioctl(listener, libc::SECCOMP_IOCTL_NOTIF_SEND, &mut response) };
    }
}

/// The `envlight` binary, to run as a child of a thread under the filter (it inherits it).
fn envlight() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
}

/// Opens the fake camera, reads `count` frames and closes it; the frames and the driver's log.
fn stream(camera: Camera, format: PixelFormat, count: usize) -> (Vec<HdrFrame>, Vec<String>) {
    let (w, h) = (camera.width, camera.height);
    let device = FakeDevice::start(camera);
    let mut source = V4l2Source::open(&device.settings(format, w, h)).unwrap();
    assert_eq!(source.format(), (format, w, h));
    let frames = (0..count)
        .map(|_| source.next_frame().unwrap().unwrap())
        .collect();
    drop(source);
    (frames, device.finish())
}

/// The content planes of a 4:2:0 frame: luma, then one plane of interleaved chroma pairs
/// (`chroma_planes` = 1) or a Cb and a Cr plane (2).
fn yuv420(width: usize, height: usize, chroma_planes: usize) -> Vec<ContentPlane> {
    let luma = ContentPlane {
        row_bytes: width,
        rows: height,
    };
    let chroma = ContentPlane {
        row_bytes: width / chroma_planes,
        rows: height / 2,
    };
    let mut planes = vec![luma];
    planes.extend(std::iter::repeat_n(chroma, chroma_planes));
    planes
}

/// A 64×48 NV12 camera in one buffer of packed rows (single-planar).
fn nv12_camera() -> Camera {
    let carriage = Carriage::Single {
        fourcc: *b"NV12",
        strides: vec![64, 64],
    };
    Camera::new(64, 48, yuv420(64, 48, 1), carriage)
}

/// The same camera as a multi-planar node, NM12 in two planes of packed rows.
fn nm12_camera() -> Camera {
    let carriage = Carriage::Multi {
        fourcc: *b"NM12",
        strides: vec![64, 64],
        data_offsets: vec![0, 0],
    };
    Camera::new(64, 48, yuv420(64, 48, 1), carriage)
}

fn assert_same_frames(a: &[HdrFrame], b: &[HdrFrame]) {
    assert_eq!(a.len(), b.len());
    for (fa, fb) in a.iter().zip(b) {
        assert_eq!((fa.width, fa.height), (fb.width, fb.height));
        assert_eq!((fa.seq, fa.time), (fb.seq, fb.time));
        assert!(fa.pixels == fb.pixels, "frame {} differs", fa.seq);
    }
    // Not a constant picture, and not the same picture twice.
    let first = &a[0].pixels;
    assert!(first.iter().any(|p| p != &first[0]), "a flat frame");
    assert!(a[1].pixels != a[0].pixels, "frames do not change");
}

/// Streams `count` frames of `single` (a single-planar camera) and of the same camera with its
/// frames carried as `multi`, and requires the same frames of both; the multi-planar frames
/// and the driver's log of that stream.
fn stream_both_ways(
    single: Camera,
    multi: Carriage,
    format: PixelFormat,
    count: usize,
) -> (Vec<HdrFrame>, Vec<String>) {
    let multi = Camera {
        carriage: multi,
        ..single.clone()
    };
    let (one_buffer, _) = stream(single, format, count);
    let (planes, log) = stream(multi, format, count);
    assert_same_frames(&planes, &one_buffer);
    (planes, log)
}

#[test]
fn two_plane_nv12_streams_as_one_buffer_nv12_does() {
    let (w, h) = (64u32, 48u32);
    let content = yuv420(64, 48, 1);
    let carriage = Carriage::Single {
        fourcc: *b"NV12",
        strides: vec![80, 80],
    };
    let single = Camera {
        corrupt: vec![1],
        short: vec![3],
        ..Camera::new(w, h, content, carriage)
    };
    let nv12 = PixelFormat::parse("NV12").unwrap();
    let multi = Carriage::Multi {
        fourcc: *b"NM12",
        strides: vec![96, 128],
        data_offsets: vec![0, 256],
    };
    let (planes, log) = stream_both_ways(single, multi, nv12, 3);
    // Frames 1 (flagged corrupt) and 3 (chroma plane cut short) are skipped by both.
    let seqs: Vec<u64> = planes.iter().map(|f| f.seq).collect();
    assert_eq!(seqs, [0, 1, 2]);
    let times: Vec<f64> = planes.iter().map(|f| f.time).collect();
    assert!((times[1] - 2.0 * 0.033_333).abs() < 1e-9, "{times:?}");
    assert!((times[2] - 4.0 * 0.033_333).abs() < 1e-9, "{times:?}");
    // The multi-planar calls, in order, and the stream closed and its buffers freed.
    let expected = [
        "QUERYCAP",
        "ENUM_FMT type 9",
        "G_FMT",
        "S_FMT",
        "S_PARM 1000/30000",
        "REQBUFS 4",
        "STREAMON",
        "STREAMOFF",
        "REQBUFS 0",
    ];
    let calls: Vec<&str> = log
        .iter()
        .map(String::as_str)
        .filter(|c| expected.contains(c))
        .collect();
    assert_eq!(calls, expected, "{log:?}");
}

#[test]
fn three_plane_yu12_streams_as_one_buffer_yu12_does() {
    let (w, h) = (64u32, 48u32);
    let carriage = Carriage::Single {
        fourcc: *b"YU12",
        strides: vec![72, 36, 36],
    };
    let single = Camera::new(w, h, yuv420(64, 48, 2), carriage);
    let yu12 = PixelFormat::parse("YU12").unwrap();
    let multi = Carriage::Multi {
        fourcc: *b"YM12",
        strides: vec![64, 40, 48],
        data_offsets: vec![16, 0, 8],
    };
    stream_both_ways(single, multi, yu12, 2);
}

#[test]
fn packed_raw_in_one_plane_of_a_multi_planar_node_streams_as_on_a_single_planar_one() {
    let (w, h) = (64u32, 32u32);
    let content = vec![ContentPlane {
        row_bytes: 80, // 64 samples of 10 bits
        rows: 32,
    }];
    let carriage = Carriage::Single {
        fourcc: *b"pRAA",
        strides: vec![96],
    };
    let single = Camera::new(w, h, content, carriage);
    let raw = PixelFormat::parse("pRAA").unwrap();
    let multi = Carriage::Multi {
        fourcc: *b"pRAA",
        strides: vec![128],
        data_offsets: vec![64],
    };
    stream_both_ways(single, multi, raw, 2);
}

#[test]
fn a_multi_planar_node_is_listed_with_its_formats() {
    use envlight::capture::v4l2::device_info;
    let camera = Camera {
        controls: exposure_controls(),
        ..nm12_camera()
    };
    let device = FakeDevice::start(camera);
    let info = device_info(&device.path).unwrap();
    drop(device.finish());
    assert!(info.multi_planar);
    assert_eq!(info.unusable, None);
    assert_eq!(info.card, "Fake camera");
    assert_eq!(info.formats.len(), 1);
    assert_eq!(info.formats[0].fourcc, "NM12");
    assert!(info.formats[0].supported);
    // Its controls, with their values read through the extended-control calls.
    let names: Vec<(&str, Option<i64>)> = info
        .controls
        .iter()
        .map(|c| (c.name.as_str(), c.value))
        .collect();
    assert_eq!(
        names,
        [
            ("Gain", Some(16)),
            ("Auto Exposure", Some(3)),
            ("Exposure Time, Absolute", Some(10)),
            // Listed, with no single value to show.
            ("Region Of Interest Rectangle", None)
        ]
    );
    let text = info.to_string();
    assert!(
        text.contains("(driver fakecam, bus platform:fake, multi-planar)"),
        "{text}"
    );
}

fn linear_settings(device: &FakeDevice, w: u32, h: u32) -> CameraSettings {
    CameraSettings {
        response: envlight::capture::response::ResponseModel::Linear,
        gain_unity: Some(16.0),
        ..device.settings(PixelFormat::Grey { bits: 8 }, w, h)
    }
}

#[test]
fn exposure_and_gain_are_read_back_from_the_controls_every_frame() {
    let (w, h) = (16u32, 8u32);
    // Codes of 100 at the camera's 1 ms and gain 2 (control 32, unity 16).
    let sensor = Sensor {
        radiance: vec![50_000.0; (w * h) as usize],
        lag: 0,
        // The camera's auto exposure doubles the exposure at frame 2.
        auto_exposure: Some((2, 20)),
    };
    let mut camera = Camera::grey(w, h, sensor);
    for c in &mut camera.controls {
        if c.id == CID_GAIN {
            c.default = 32;
        }
    }
    let device = FakeDevice::start(camera);
    let mut source = V4l2Source::open(&linear_settings(&device, w, h)).unwrap();
    let frames: Vec<HdrFrame> = (0..4)
        .map(|_| source.next_frame().unwrap().unwrap())
        .collect();
    drop(source);
    let log = device.finish();
    // The codes doubled with the exposure …
    assert!(
        log.contains(&"frame 1 taken at 0.001 s, gain 2".to_string()),
        "{log:?}"
    );
    assert!(
        log.contains(&"frame 2 taken at 0.002 s, gain 2".to_string()),
        "{log:?}"
    );
    // … and the radiance did not: 100/255 / (1 ms × 2) = 200/255 / (2 ms × 2).
    let expected = 100.0 / 255.0 / 0.002;
    for f in &frames {
        for p in &f.pixels {
            for c in p {
                assert!(
                    (f64::from(*c) / expected - 1.0).abs() < 1e-6,
                    "frame {}: {c}",
                    f.seq
                );
            }
        }
    }
}

/// A scene whose radiance spans 2^10 : 1 (in code values of a 1 s exposure at unity gain): a
/// horizontal ramp, brighter by powers of two.
fn wide_scene(width: u32, height: u32) -> Vec<f64> {
    (0..width * height)
        .map(|i| {
            let x = f64::from(i % width) / f64::from(width - 1);
            300.0 * 2f64.powf(10.0 * x)
        })
        .collect()
}

#[test]
fn brackets_are_taken_through_the_exposure_control_and_merged() {
    let (w, h) = (64u32, 4u32);
    let radiance = wide_scene(w, h);
    let sensor = Sensor {
        radiance: radiance.clone(),
        // The driver applies a new exposure two frames late; the settle frames absorb that.
        lag: 2,
        auto_exposure: None,
    };
    let device = FakeDevice::start(Camera::grey(w, h, sensor));
    let settings = CameraSettings {
        bracket_exposures_s: vec![0.0005, 0.004, 0.032],
        settle_frames: 2,
        ..linear_settings(&device, w, h)
    };
    let mut source = V4l2Source::open(&settings).unwrap();
    let frames: Vec<HdrFrame> = (0..2)
        .map(|_| source.next_frame().unwrap().unwrap())
        .collect();
    drop(source);
    let log = device.finish();
    // Manual exposure, then per bracket: the exposure set, two frames dropped, one kept.
    let sets: Vec<&str> = log
        .iter()
        .map(String::as_str)
        .filter(|l| l.starts_with("S_CTRL Exposure Time"))
        .collect();
    assert_eq!(
        sets,
        [
            "S_CTRL Exposure Time, Absolute 5 at frame 0",
            "S_CTRL Exposure Time, Absolute 40 at frame 3",
            "S_CTRL Exposure Time, Absolute 320 at frame 6",
            "S_CTRL Exposure Time, Absolute 5 at frame 9",
            "S_CTRL Exposure Time, Absolute 40 at frame 12",
            "S_CTRL Exposure Time, Absolute 320 at frame 15",
        ],
        "{log:?}"
    );
    assert!(
        log.contains(&"S_CTRL Auto Exposure 1 at frame 0".to_string()),
        "{log:?}"
    );
    for kept in [
        "frame 2 taken at 0.0005 s",
        "frame 5 taken at 0.004 s",
        "frame 8 taken at 0.032 s",
    ] {
        assert!(log.iter().any(|l| l.starts_with(kept)), "{kept}: {log:?}");
    }
    // The merge recovers the scene (code/255 per second of exposure) across its 2^10 range.
    for f in &frames {
        let errors: Vec<f64> = f
            .pixels
            .iter()
            .zip(&radiance)
            .map(|(p, l)| (f64::from(p[1]) / (l / 255.0) - 1.0).abs())
            .collect();
        let worst = errors.iter().cloned().fold(0.0, f64::max);
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        println!(
            "merged frame {}: relative error mean {mean:.4}, worst {worst:.4}",
            f.seq
        );
        // Bounded by quantisation: the darkest pixel gives 9.6 codes in the longest bracket,
        // so half a code is 5.2% of it.
        assert!(worst < 0.053 && mean < 0.01, "mean {mean}, worst {worst}");
    }
}

#[test]
fn a_lost_device_is_an_error_naming_it_and_closing_it_does_not_panic() {
    for camera in [nv12_camera(), nm12_camera()] {
        let camera = Camera {
            lost_at: Some(2),
            ..camera
        };
        let device = FakeDevice::start(camera);
        let nv12 = PixelFormat::parse("NV12").unwrap();
        let mut source = V4l2Source::open(&device.settings(nv12, 64, 48)).unwrap();
        for _ in 0..2 {
            source.next_frame().unwrap().unwrap();
        }
        let e = source.next_frame().unwrap_err().to_string();
        assert!(e.contains(&device.path.display().to_string()), "{e}");
        assert!(e.contains("No such device"), "{e}");
        // Stopping the stream fails with EIO, and so freeing its buffers with EBUSY: a
        // warning, not a crash (the `v4l` crate's stream aborted the process here).
        drop(source);
        let log = device.finish();
        assert!(
            log.contains(&"STREAMOFF failed: EIO".to_string()),
            "{log:?}"
        );
        assert!(
            log.contains(&"REQBUFS failed: EBUSY".to_string()),
            "{log:?}"
        );
    }
}

/// The filter is inherited by child processes, and the driver reads and writes their memory
/// too: the command line's camera path, end to end.
#[test]
fn envlight_decompose_captures_from_the_camera_end_to_end() {
    let (w, h) = (64u32, 32u32);
    // Code 100 everywhere at the camera's 1 ms.
    let sensor = Sensor {
        radiance: vec![100_000.0; (w * h) as usize],
        lag: 0,
        auto_exposure: None,
    };
    let device = FakeDevice::start(Camera::grey(w, h, sensor));
    let path = device.path.display().to_string();
    let output = envlight()
        .args([
            "decompose",
            "--device",
            &path,
            "--frames",
            "3",
            "--lights",
            "16",
        ])
        .args(["--projection", "latlong", "--no-filter"])
        .output()
        .unwrap();
    let log = device.finish();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("GREY 64x32"), "{stderr}");
    assert!(log.contains(&"STREAMON".to_string()), "{log:?}");
    let lines: Vec<serde_json::Value> = String::from_utf8(output.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 3);
    // sRGB code 100 over 1 ms, the same in every direction: the lights sum to 4π times it.
    let code = 100.0 / 255.0;
    let radiance = ((code + 0.055) / 1.055f64).powf(2.4) / 0.001;
    let expected = 4.0 * std::f64::consts::PI * radiance;
    for line in &lines {
        let lights = line["lights"].as_array().unwrap();
        assert_eq!(lights.len(), 16);
        let sum: f64 = lights.iter().map(|l| l["rgb"][1].as_f64().unwrap()).sum();
        assert!(
            (sum / expected - 1.0).abs() < 1e-3,
            "Σ {sum} against {expected}"
        );
    }
}

#[test]
fn a_camera_unplugged_and_plugged_in_again_is_reopened_and_streams_on() {
    use envlight::capture::resilient::{ResilientSource, RetryPolicy};
    let camera = Camera {
        lost_at: Some(3),
        unplugged_opens: 4,
        ..nm12_camera()
    };
    let device = FakeDevice::start(camera);
    let nv12 = PixelFormat::parse("NV12").unwrap();
    let settings = device.settings(nv12, 64, 48);
    let policy = RetryPolicy {
        initial_backoff: Duration::from_millis(1),
        max_backoff: Duration::from_millis(8),
        max_attempts: None,
    };
    let mut source = ResilientSource::new("camera", policy, move || {
        Ok(Box::new(V4l2Source::open(&settings)?) as Box<dyn FrameSource>)
    });
    let health = source.health().unwrap();
    let frames: Vec<HdrFrame> = (0..6)
        .map(|_| source.next_frame().unwrap().unwrap())
        .collect();
    drop(source);
    let log = device.finish();
    // Three frames, the loss, four failed opens, then the camera again from its frame 3.
    let failed = log
        .iter()
        .filter(|l| *l == "QUERYCAP failed: ENODEV")
        .count();
    assert_eq!(failed, 4, "{log:?}");
    assert!(log.contains(&"back".to_string()), "{log:?}");
    assert_eq!(
        log.iter().filter(|l| *l == "STREAMON").count(),
        2,
        "{log:?}"
    );
    let seqs: Vec<u64> = frames.iter().map(|f| f.seq).collect();
    assert_eq!(seqs, [0, 1, 2, 3, 4, 5], "sequence numbers continue");
    assert!(frames.windows(2).all(|w| w[1].time >= w[0].time));
    assert!(!health.is_stale());
    assert_eq!(health.reconnect_attempts(), 0);
    assert_eq!(health.failures_total(), 5, "the loss and four failed opens");
    assert!(
        health.last_error().contains("No such device"),
        "{}",
        health.last_error()
    );
    // The frames after the reconnect are the camera's frames 3, 4, 5.
    let direct = stream(nv12_camera(), nv12, 6).0;
    for (a, b) in frames.iter().zip(&direct) {
        assert!(a.pixels == b.pixels, "frame {}", a.seq);
    }
}

#[test]
fn two_plane_nv16_streams_as_one_buffer_nv16_does() {
    let (w, h) = (64u32, 48u32);
    // Luma, then a row of interleaved Cb Cr for every luma row.
    let row = ContentPlane {
        row_bytes: 64,
        rows: 48,
    };
    let content = vec![row.clone(), row];
    let carriage = Carriage::Single {
        fourcc: *b"NV16",
        strides: vec![72, 72],
    };
    let single = Camera::new(w, h, content, carriage);
    let nv16 = PixelFormat::parse("NV16").unwrap();
    let multi = Carriage::Multi {
        fourcc: *b"NM16",
        strides: vec![64, 96],
        data_offsets: vec![0, 128],
    };
    stream_both_ways(single, multi, nv16, 2);
}

/// A 10-bit `P010` camera (HDMI capture of HDR video, the 10-bit output of an ISP) with padded
/// rows: negotiated, its 16-bit words read at the driver's stride, every frame finite,
/// non-negative and its own.
#[test]
fn p010_streams_from_a_camera_with_padded_rows() {
    let (w, h) = (64u32, 48u32);
    // Luma rows of 64 words, then 24 rows of 32 interleaved Cb Cr word pairs, 160 bytes apart.
    let content = vec![
        ContentPlane {
            row_bytes: 128,
            rows: 48,
        },
        ContentPlane {
            row_bytes: 128,
            rows: 24,
        },
    ];
    let carriage = Carriage::Single {
        fourcc: *b"P010",
        strides: vec![160, 160],
    };
    let p010 = PixelFormat::parse("P010").unwrap();
    let (frames, log) = stream(Camera::new(w, h, content, carriage), p010, 3);
    assert!(log.iter().any(|l| l.starts_with("S_FMT")), "{log:?}");
    for f in &frames {
        assert_eq!((f.width, f.height), (w, h));
        assert!(
            f.pixels
                .iter()
                .flatten()
                .all(|v| v.is_finite() && *v >= 0.0),
            "frame {}",
            f.seq
        );
    }
    assert!(frames[1].pixels != frames[0].pixels, "frames do not change");
    let first = &frames[0].pixels;
    assert!(first.iter().any(|p| p != &first[0]), "a flat frame");
}

/// Motion JPEG as UVC webcams send it: frames of varying length in buffers of a fixed size
/// (`bytesused` below the length), decoded to the same radiance as RGB24 frames of the decoded
/// pixels; a frame cut short in transfer is skipped.
#[test]
fn mjpeg_frames_of_varying_length_decode_as_their_pixels_do() {
    use envlight::capture::pixel_format::{decode, RawFrame, YuvMatrix};
    let (w, h) = (64u32, 48u32);
    let jpegs: Vec<Vec<u8>> = (0..3u32)
        .map(|k| {
            let rgb: Vec<u8> = (0..w * h)
                .flat_map(|i| {
                    let (x, y) = (i % w, i / w);
                    [
                        (x * 4 + k * 40) as u8,
                        (y * 5) as u8,
                        ((x + y) * 2 + k * 70) as u8,
                    ]
                })
                .collect();
            let mut out = Vec::new();
            jpeg_encoder::Encoder::new(&mut out, 80 + 5 * k as u8)
                .encode(&rgb, w as u16, h as u16, jpeg_encoder::ColorType::Rgb)
                .unwrap();
            out
        })
        .collect();
    let lengths: Vec<usize> = jpegs.iter().map(Vec::len).collect();
    assert!(lengths.windows(2).all(|p| p[0] != p[1]), "{lengths:?}");
    // Their pixels as the decoder makes them, as RGB24 frames.
    let rgb24: Vec<Vec<u8>> = jpegs
        .iter()
        .map(|jpeg| {
            let raw = RawFrame {
                data: jpeg,
                format: PixelFormat::Mjpeg,
                width: w,
                height: h,
                stride: 0,
            };
            let codes = decode(&raw, YuvMatrix::Auto).unwrap();
            codes
                .pixels
                .iter()
                .flatten()
                .map(|v| (v * 255.0).round() as u8)
                .collect()
        })
        .collect();
    let grey_content = vec![ContentPlane {
        row_bytes: 1,
        rows: 1,
    }];
    let camera = |fourcc: &[u8; 4], payloads: Vec<Vec<u8>>| Camera {
        payloads,
        short: vec![1],
        ..Camera::new(
            w,
            h,
            grey_content.clone(),
            Carriage::Single {
                fourcc: *fourcc,
                strides: vec![0],
            },
        )
    };
    let (mjpeg, _) = stream(camera(b"MJPG", jpegs), PixelFormat::Mjpeg, 3);
    let (rgb, _) = stream(camera(b"RGB3", rgb24), PixelFormat::Rgb24, 3);
    // Frames 0, 2 and 3 (frame 1 came short), and the pictures differ.
    assert_same_frames(&mjpeg, &rgb);
    assert!((mjpeg[1].time - 2.0 * 0.033_333).abs() < 1e-9);
}

/// The daemon on a camera: the lights of its frames reach a client; unplugged, the last
/// lights are served marked stale (and the metrics say so); plugged in again, fresh lights
/// follow.
#[test]
fn the_daemon_serves_a_cameras_lights_stale_while_it_is_unplugged() {
    use envlight::daemon::{Daemon, DaemonOptions};
    use envlight::stream::client::{Client, Endpoint};
    use envlight::stream::{FrameMessage, Message, Request};
    let (w, h) = (32u32, 16u32);
    let sensor = Sensor {
        radiance: vec![100_000.0; (w * h) as usize],
        lag: 0,
        auto_exposure: None,
    };
    let camera = Camera {
        frame_interval: Some(Duration::from_millis(20)),
        ..Camera::grey(w, h, sensor)
    };
    let device = FakeDevice::start(camera);
    let dir = tempfile::tempdir().unwrap();
    let extra = format!(
        "[source]\nkind = \"v4l2\"\nprojection = \"latlong\"\n[camera]\ndevice = \"{}\"\n\
         formats = [\"GREY\"]\nresponse = \"linear\"\nretry_initial_s = 0.01\n\
         retry_max_s = 0.02\n[decompose]\nlights = 8\nworking_width = 16\n",
        device.path.display()
    );
    let config = common::config(dir.path(), 0.5, &extra);
    let daemon = Daemon::start(config, DaemonOptions::default()).unwrap();
    let uds = daemon.addresses().stream.unix_socket.clone().unwrap();
    let metrics = daemon.addresses().metrics.unwrap();
    let mut client = Client::connect(
        &Endpoint::Unix(uds),
        &Request::default(),
        Some(common::TIMEOUT),
    )
    .unwrap();
    let mut next_frame = || -> FrameMessage {
        match client.next_message() {
            Ok(Some(Message::Frame(frame))) => frame,
            other => panic!("{other:?}"),
        }
    };
    // Linear code 100 over 1 ms everywhere: the lights sum to 4π times that.
    let expected = 4.0 * std::f64::consts::PI * (100.0 / 255.0) / 0.001;
    let sum = |f: &FrameMessage| f.lights.iter().map(|l| f64::from(l.rgb[1])).sum::<f64>();
    for _ in 0..3 {
        let frame = next_frame();
        assert!(!frame.stale);
        assert_eq!(frame.lights.len(), 8);
        assert!(
            (sum(&frame) / expected - 1.0).abs() < 1e-3,
            "{}",
            sum(&frame)
        );
    }
    device.present.store(false, Ordering::SeqCst);
    let stale = loop {
        let frame = next_frame();
        if frame.stale {
            break frame;
        }
    };
    assert!(
        (sum(&stale) / expected - 1.0).abs() < 1e-3,
        "the last lights, marked stale"
    );
    let (_, text) = common::http_get(metrics, "/metrics");
    assert_eq!(
        common::metric_value(&text, "envlight_source_stale"),
        1.0,
        "{text}"
    );
    device.present.store(true, Ordering::SeqCst);
    let fresh = loop {
        let frame = next_frame();
        if !frame.stale {
            break frame;
        }
    };
    assert!(fresh.seq > stale.seq, "{} after {}", fresh.seq, stale.seq);
    assert!((sum(&fresh) / expected - 1.0).abs() < 1e-3);
    common::wait_until("fresh metrics", || {
        let (_, text) = common::http_get(metrics, "/metrics");
        common::metric_value(&text, "envlight_source_stale") == 0.0
    });
    daemon.shutdown().unwrap();
    let log = device.finish();
    assert!(
        log.iter().any(|l| l == "QUERYCAP failed: ENODEV"),
        "reopened while away: {log:?}"
    );
}

/// `envlight devices DEVICE` lists the named camera (a child process under the filter).
#[test]
fn envlight_devices_lists_a_named_multi_planar_camera() {
    let camera = Camera {
        controls: exposure_controls(),
        ..nm12_camera()
    };
    let device = FakeDevice::start(camera);
    let path = device.path.display().to_string();
    let output = envlight().args(["devices", &path]).output().unwrap();
    let missing = envlight()
        .args(["devices", &path, "/no/such/camera"])
        .output()
        .unwrap();
    drop(device.finish());
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(
        stdout.starts_with(&format!(
            "{path}: Fake camera (driver fakecam, bus platform:fake, multi-planar)\n"
        )),
        "{stdout}"
    );
    assert!(stdout.contains("  format NM12 (fake format)\n"), "{stdout}");
    assert!(
        stdout.contains("Exposure Time, Absolute: 10 (min 1, max 10000"),
        "{stdout}"
    );
    // A camera that is not there: the others are listed, the exit status is 1 and the error
    // names it.
    assert_eq!(missing.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&missing.stdout).contains("format NM12"));
    let stderr = String::from_utf8_lossy(&missing.stderr);
    assert!(stderr.contains("/no/such/camera: No such file"), "{stderr}");
}

/// `envlight calibrate-fisheye --device` finds the image circle of a live frame.
#[test]
fn calibrate_fisheye_measures_the_circle_of_a_live_frame() {
    let (w, h) = (96u32, 80u32);
    let (cx, cy, r) = (47.3, 40.6, 33.2);
    // A bright disc (code ~200 at 1 ms) on a dark surround (code ~2), its edge anti-aliased
    // by 8 × 8 supersampling.
    let radiance: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = (f64::from(i % w), f64::from(i / w));
            let mut inside = 0;
            for sy in 0..8 {
                for sx in 0..8 {
                    let px = x + (f64::from(sx) + 0.5) / 8.0;
                    let py = y + (f64::from(sy) + 0.5) / 8.0;
                    inside += i32::from((px - cx).hypot(py - cy) <= r);
                }
            }
            2_000.0 + 198_000.0 * f64::from(inside) / 64.0
        })
        .collect();
    let sensor = Sensor {
        radiance,
        lag: 0,
        auto_exposure: None,
    };
    let device = FakeDevice::start(Camera::grey(w, h, sensor));
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("camera.toml");
    std::fs::write(
        &config,
        "[camera]\nformats = [\"GREY\"]\nwidth = 96\nheight = 80\n",
    )
    .unwrap();
    let path = device.path.display().to_string();
    let output = envlight()
        .args([
            "calibrate-fisheye",
            "--device",
            &path,
            "--model",
            "equisolid",
        ])
        .args([
            "--fov".as_ref(),
            "185".as_ref(),
            "--config".as_ref(),
            config.as_os_str(),
        ])
        .output()
        .unwrap();
    let log = device.finish();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    // The fifth frame was measured.
    assert!(
        log.iter().any(|l| l.starts_with("frame 4 taken")),
        "{log:?}"
    );
    assert!(
        stdout.contains(&format!("# envlight calibrate-fisheye {path} (V4L2 camera")),
        "{stdout}"
    );
    let value = |key: &str| -> Vec<f64> {
        let line = stdout.lines().find(|l| l.starts_with(key)).unwrap();
        line.split('=')
            .nth(1)
            .unwrap()
            .trim_matches(|c: char| c == ' ' || c == '[' || c == ']')
            .split(',')
            .map(|v| v.trim().parse().unwrap())
            .collect()
    };
    let center = value("center");
    let radius = value("radius")[0];
    println!("center {center:?} radius {radius}");
    assert!(
        (center[0] - cx).abs() < 0.5 && (center[1] - cy).abs() < 0.5,
        "{stdout}"
    );
    assert!((radius - r).abs() < 0.5, "{stdout}");
    assert!(stdout.contains("model = \"equisolid\"") && stdout.contains("fov_deg = 185.0"));
}

/// `envlight calibrate-response --device` captures the brackets through the exposure control
/// and recovers the fake sensor's linear response.
#[test]
fn calibrate_response_recovers_a_linear_sensor_from_live_brackets() {
    use envlight::capture::response::ResponseCurve;
    let (w, h) = (64u32, 32u32);
    let sensor = Sensor {
        radiance: wide_scene(w, h),
        lag: 1,
        auto_exposure: None,
    };
    let device = FakeDevice::start(Camera::grey(w, h, sensor));
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("camera.toml");
    std::fs::write(
        &config,
        "[camera]\nformats = [\"GREY\"]\nwidth = 64\nheight = 32\nsettle_frames = 2\n",
    )
    .unwrap();
    let curve_path = dir.path().join("curve.txt");
    let path = device.path.display().to_string();
    let output = envlight()
        .args(["calibrate-response", "--device", &path])
        .args(["--exposures", "0.001,0.004,0.016", "--levels", "256"])
        .args(["--config".as_ref(), config.as_os_str()])
        .args(["-o".as_ref(), curve_path.as_os_str()])
        .output()
        .unwrap();
    let log = device.finish();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    for kept in [
        "frame 2 taken at 0.001 s",
        "frame 5 taken at 0.004 s",
        "frame 8 taken at 0.016 s",
    ] {
        assert!(log.iter().any(|l| l.starts_with(kept)), "{kept}: {log:?}");
    }
    let curve = ResponseCurve::read(&curve_path).unwrap();
    for (a, b) in [(0.1, 0.2), (0.2, 0.4), (0.4, 0.8), (0.1, 0.8)] {
        let ratio = curve.eval(1, b) / curve.eval(1, a);
        println!("X({b}) / X({a}) = {ratio:.4} (linear: {})", b / a);
        // Within 5% of linear (8-bit codes and the solve's smoothness; 3.4% at most seen).
        assert!(
            (ratio / (b / a) - 1.0).abs() < 0.05,
            "X({b}) / X({a}) = {ratio}"
        );
    }
}

/// A signal during the wait (EINTR) or a wake-up with no buffer ready (EAGAIN) is waited out
/// without losing a frame, through either API; a camera that stops delivering is a timeout
/// error after the configured time, naming the device.
#[test]
fn interrupted_or_empty_dequeues_are_retried_and_a_stalled_camera_times_out() {
    for camera in [nv12_camera(), nm12_camera()] {
        let camera = Camera {
            dequeue_hiccups: vec![(1, libc::EINTR), (2, libc::EAGAIN), (3, libc::EINTR)],
            stalled_from: Some(4),
            ..camera
        };
        let device = FakeDevice::start(camera);
        let path = device.path.display().to_string();
        let nv12 = PixelFormat::parse("NV12").unwrap();
        let settings = CameraSettings {
            timeout: Duration::from_millis(300),
            ..device.settings(nv12, 64, 48)
        };
        let mut source = V4l2Source::open(&settings).unwrap();
        let times: Vec<f64> = (0..4)
            .map(|_| source.next_frame().unwrap().unwrap().time)
            .collect();
        // Frames 0–3 in order, none skipped.
        for (k, t) in times.iter().enumerate() {
            assert!((t - k as f64 * 0.033_333).abs() < 1e-9, "{times:?}");
        }
        let started = std::time::Instant::now();
        let e = source.next_frame().unwrap_err().to_string();
        let waited = started.elapsed();
        drop(source);
        let log = device.finish();
        assert_eq!(
            log.iter().filter(|l| l.starts_with("DQBUF ")).count(),
            3,
            "{log:?}"
        );
        assert!(e.contains("no frame within the timeout"), "{e}");
        assert!(e.contains(&path), "{e}");
        // Not before the timeout, and not long after it (a loop bounded by the timeout).
        assert!(waited >= Duration::from_millis(300), "{waited:?}");
        assert!(waited < Duration::from_secs(5), "{waited:?}");
    }
}

/// A camera that offers none of the configured formats, or that sets another format than the
/// one asked for, is refused with an error that names what it has or chose.
#[test]
fn a_format_the_camera_does_not_give_is_an_error_naming_what_it_has() {
    let device = FakeDevice::start(nv12_camera());
    let e = V4l2Source::open(&device.settings(PixelFormat::PackedYuv(PackedYuv::Yuyv), 64, 48))
        .err()
        .unwrap()
        .to_string();
    drop(device.finish());
    assert!(
        e.contains("none of the configured formats is offered; the camera has NV12"),
        "{e}"
    );
    let device = FakeDevice::start(Camera {
        substitute: Some(*b"YUYV"),
        ..nv12_camera()
    });
    let nv12 = PixelFormat::parse("NV12").unwrap();
    let e = V4l2Source::open(&device.settings(nv12, 64, 48))
        .err()
        .unwrap()
        .to_string();
    drop(device.finish());
    assert!(e.contains("asked for NV12, the driver chose YUYV"), "{e}");
}

/// A configured exposure time turns the camera's auto exposure off and sets the time; the
/// radiance follows it.
#[test]
fn a_configured_exposure_is_set_manual_and_used() {
    let (w, h) = (16u32, 8u32);
    let sensor = Sensor {
        radiance: vec![50_000.0; (w * h) as usize],
        lag: 0,
        // The camera's auto exposure would change the time at frame 1: not in manual mode.
        auto_exposure: Some((1, 7)),
    };
    let device = FakeDevice::start(Camera::grey(w, h, sensor));
    let settings = CameraSettings {
        exposure_s: Some(0.002),
        ..linear_settings(&device, w, h)
    };
    let mut source = V4l2Source::open(&settings).unwrap();
    let frames: Vec<HdrFrame> = (0..3)
        .map(|_| source.next_frame().unwrap().unwrap())
        .collect();
    drop(source);
    let log = device.finish();
    let sets: Vec<&str> = (log.iter().map(String::as_str))
        .filter(|l| l.starts_with("S_CTRL"))
        .collect();
    assert_eq!(
        sets,
        [
            "S_CTRL Auto Exposure 1 at frame 0",
            "S_CTRL Exposure Time, Absolute 20 at frame 0"
        ]
    );
    assert!(
        log.contains(&"frame 2 taken at 0.002 s, gain 1".to_string()),
        "{log:?}"
    );
    // Code 100 at 2 ms and unity gain.
    let expected = 100.0 / 255.0 / 0.002;
    for f in &frames {
        let v = f64::from(f.pixels[0][1]);
        assert!((v / expected - 1.0).abs() < 1e-6, "frame {}: {v}", f.seq);
    }
}

/// A card name (and a format description) the driver cut in the middle of a UTF-8 sequence (a
/// USB camera's product name in Chinese, 32 bytes at most) is read lossily: the camera opens
/// and streams.
#[test]
fn a_camera_whose_name_is_cut_mid_character_opens() {
    let name = "USB 高清广角鱼眼摄像头 HDR Camera".as_bytes();
    let card = name[..30].to_vec();
    assert!(
        std::str::from_utf8(&card).is_err(),
        "the cut splits a character"
    );
    let camera = Camera {
        card: card.clone(),
        format_description: card,
        ..nv12_camera()
    };
    let device = FakeDevice::start(camera);
    let nv12 = PixelFormat::parse("NV12").unwrap();
    let mut source = V4l2Source::open(&device.settings(nv12, 64, 48)).unwrap();
    source.next_frame().unwrap().unwrap();
    let described = source.describe();
    drop(source);
    let info = envlight::capture::v4l2::device_info(&device.path).unwrap();
    drop(device.finish());
    assert!(
        described.contains("(USB 高清广角鱼眼摄像\u{fffd})"),
        "{described}"
    );
    assert_eq!(info.card, "USB 高清广角鱼眼摄像\u{fffd}");
    assert_eq!(info.formats[0].description, "USB 高清广角鱼眼摄像\u{fffd}");
}
