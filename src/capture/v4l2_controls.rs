//! A V4L2 node's controls: enumerated (`VIDIOC_QUERY_EXT_CTRL` with
//! `V4L2_CTRL_FLAG_NEXT_CTRL | V4L2_CTRL_FLAG_NEXT_COMPOUND`) and read (`VIDIOC_G_EXT_CTRLS`)
//! with the kernel's structures, whatever their type.
//!
//! The `v4l` crate's enumeration unwraps the control type into the types it knows and the name
//! into UTF-8; one control of a newer type — `V4L2_CTRL_TYPE_RECT`, which UVC cameras have had
//! since Linux 6.15 (2025) for their region of interest — made it panic, and envlight lost every
//! control of such a camera: the exposure and gain it reads back each frame for the radiance,
//! and bracketing. Here a type is kept as its number and a name is read lossily.

use super::v4l2_stream::{ioctl, kernel_string, named};
use std::io;
use v4l::device::Handle;
use v4l::v4l2::vidioc;
use v4l::v4l_sys::{v4l2_ext_control, v4l2_ext_controls, v4l2_query_ext_ctrl};

/// `V4L2_CTRL_FLAG_NEXT_CTRL`.
const NEXT_CTRL: u32 = 0x8000_0000;
/// `V4L2_CTRL_FLAG_NEXT_COMPOUND`.
const NEXT_COMPOUND: u32 = 0x4000_0000;
/// `V4L2_CTRL_TYPE_INTEGER`, `_BOOLEAN`, `_MENU`, `_INTEGER64`, `_INTEGER_MENU`.
const INTEGER: u32 = 1;
const BOOLEAN: u32 = 2;
const MENU: u32 = 3;
const INTEGER64: u32 = 5;
const INTEGER_MENU: u32 = 9;

/// One control as the driver describes it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ControlDesc {
    pub id: u32,
    /// `V4L2_CTRL_TYPE_*`.
    pub kind: u32,
    pub name: String,
    pub minimum: i64,
    pub maximum: i64,
    pub step: u64,
    pub default: i64,
}

impl ControlDesc {
    /// Whether its value is one number ([`read_control`] reads it).
    pub fn is_numeric(&self) -> bool {
        matches!(
            self.kind,
            INTEGER | BOOLEAN | MENU | INTEGER64 | INTEGER_MENU
        )
    }
}

/// Every control of the node, in the driver's order.
pub fn query_controls(handle: &Handle) -> io::Result<Vec<ControlDesc>> {
    let mut controls = Vec::new();
    let mut id = 0;
    // A node has a few dozen controls; the bound keeps a broken driver from looping forever.
    for _ in 0..4096 {
        // SAFETY: all-zero is a valid v4l2_query_ext_ctrl (integers and bytes).
        let mut query: v4l2_query_ext_ctrl = unsafe { std::mem::zeroed() };
        query.id = id | NEXT_CTRL | NEXT_COMPOUND;
        // SAFETY: VIDIOC_QUERY_EXT_CTRL reads and writes a v4l2_query_ext_ctrl.
        match unsafe { ioctl(handle, vidioc::VIDIOC_QUERY_EXT_CTRL, &mut query) } {
            Ok(()) => {}
            // The end of the list (or a node without controls).
            Err(e) if e.raw_os_error() == Some(libc::EINVAL) => break,
            Err(e) => return Err(named("VIDIOC_QUERY_EXT_CTRL", e)),
        }
        if query.id <= id {
            // A driver that does not move on: stop rather than loop.
            break;
        }
        id = query.id;
        controls.push(ControlDesc {
            id: query.id,
            kind: query.type_,
            name: kernel_string(&query.name.map(|c| c as u8)),
            minimum: query.minimum,
            maximum: query.maximum,
            step: query.step,
            default: query.default_value,
        });
    }
    Ok(controls)
}

/// The current value of a numeric control (`None` for other types).
pub fn read_control(handle: &Handle, control: &ControlDesc) -> io::Result<Option<i64>> {
    if !control.is_numeric() {
        return Ok(None);
    }
    // SAFETY: all-zero is a valid v4l2_ext_control and v4l2_ext_controls (`which` 0: the
    // current values).
    let mut value: v4l2_ext_control = unsafe { std::mem::zeroed() };
    value.id = control.id;
    let mut list: v4l2_ext_controls = unsafe { std::mem::zeroed() };
    list.count = 1;
    list.controls = &mut value;
    // SAFETY: VIDIOC_G_EXT_CTRLS reads the list and writes its one control, which outlives the
    // call.
    unsafe { ioctl(handle, vidioc::VIDIOC_G_EXT_CTRLS, &mut list) }
        .map_err(|e| named(&format!("VIDIOC_G_EXT_CTRLS {:#x}", control.id), e))?;
    // SAFETY: a 64-bit control carries its value in `value64`, the others in `value`.
    Ok(Some(unsafe {
        if control.kind == INTEGER64 {
            value.__bindgen_anon_1.value64
        } else {
            i64::from(value.__bindgen_anon_1.value)
        }
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_node_without_controls_has_none_and_others_fail_naming_the_request() {
        // /dev/null answers no V4L2 request: ENOTTY, an error (not the end of the list).
        let device = v4l::Device::with_path("/dev/null").unwrap();
        let e = query_controls(&device.handle()).unwrap_err();
        assert!(e.to_string().starts_with("VIDIOC_QUERY_EXT_CTRL: "), "{e}");
        let exposure = ControlDesc {
            id: 0x009a_0902,
            kind: INTEGER,
            name: "Exposure".into(),
            minimum: 1,
            maximum: 10_000,
            step: 1,
            default: 100,
        };
        let e = read_control(&device.handle(), &exposure).unwrap_err();
        assert!(
            e.to_string().starts_with("VIDIOC_G_EXT_CTRLS 0x9a0902: "),
            "{e}"
        );
        let rect = ControlDesc {
            kind: 0x0107,
            ..exposure
        };
        assert!(!rect.is_numeric());
        assert_eq!(read_control(&device.handle(), &rect).unwrap(), None);
    }
}
