//! V4L2 controls by the names `v4l2-ctl --list-ctrls` shows, checked against what the driver
//! says of each before they are set.

use super::{ioctl, sys};
use crate::source::ControlProblem;
use std::os::fd::OwnedFd;
use stereoscope_rig::schema::ControlValue;

/// A control's name as `v4l2-ctl` shows it: lower case, runs of anything but letters and
/// digits as one `_` ("Exposure Time, Absolute" → `exposure_time_absolute`).
pub(super) fn control_name(driver_name: &str) -> String {
    let mut out = String::new();
    for c in driver_name.chars() {
        if c.is_ascii_alphanumeric() {
            out.push(c.to_ascii_lowercase());
        } else if !out.is_empty() && !out.ends_with('_') {
            out.push('_');
        }
    }
    out.trim_end_matches('_').to_string()
}

/// The device's controls (enabled ones), by the driver's enumeration.
pub(super) fn list_controls(fd: &OwnedFd) -> Vec<sys::QueryCtrl> {
    let mut out = Vec::new();
    let mut id = sys::CTRL_FLAG_NEXT_CTRL;
    // Bounded: a driver lists a few dozen.
    for _ in 0..1024 {
        let mut q: sys::QueryCtrl = sys::zeroed();
        q.id = id;
        if ioctl(fd, sys::VIDIOC_QUERYCTRL, &mut q).is_err() {
            break;
        }
        id = q.id | sys::CTRL_FLAG_NEXT_CTRL;
        if q.flags & sys::CTRL_FLAG_DISABLED == 0 && q.type_ != sys::CTRL_TYPE_CTRL_CLASS {
            out.push(q);
        }
    }
    out
}

/// The id and value of control `name` = `value`, checked against what the driver says of it.
pub(super) fn control_value(
    fd: &OwnedFd,
    known: &[sys::QueryCtrl],
    name: &str,
    value: &ControlValue,
) -> Result<(u32, i64), ControlProblem> {
    let Some(q) = known
        .iter()
        .find(|q| control_name(&sys::c_name(&q.name)) == name)
    else {
        let names: Vec<String> = known
            .iter()
            .map(|q| control_name(&sys::c_name(&q.name)))
            .filter(|n| !n.is_empty())
            .collect();
        return Err(ControlProblem::Unknown { known: names });
    };
    let (min, max) = (q.minimum as i64, q.maximum as i64);
    let v = match value {
        ControlValue::Bool(b) => *b as i64,
        ControlValue::Integer(i) => *i,
        ControlValue::Item(item) => {
            if q.type_ != sys::CTRL_TYPE_MENU {
                return Err(ControlProblem::NotAMenu {
                    item: item.clone(),
                    min,
                    max,
                });
            }
            let mut items = Vec::new();
            for index in q.minimum.max(0)..=q.maximum.min(255) {
                let mut m: sys::QueryMenu = sys::zeroed();
                m.id = q.id;
                m.index = index as u32;
                if ioctl(fd, sys::VIDIOC_QUERYMENU, &mut m).is_ok() {
                    let text = sys::c_name(&{ m.name });
                    if control_name(&text) == control_name(item) {
                        return Ok((q.id, index as i64));
                    }
                    items.push(text);
                }
            }
            return Err(ControlProblem::NoSuchItem {
                item: item.clone(),
                items,
            });
        }
    };
    if !(min..=max).contains(&v) {
        return Err(ControlProblem::OutOfRange {
            value: value.to_string(),
            min,
            max,
        });
    }
    Ok((q.id, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn control_names_are_v4l2_ctls() {
        assert_eq!(
            control_name("Exposure Time, Absolute"),
            "exposure_time_absolute"
        );
        assert_eq!(control_name("Test Pattern"), "test_pattern");
        assert_eq!(
            control_name("White Balance, Automatic "),
            "white_balance_automatic"
        );
        assert_eq!(control_name("100% Black"), "100_black");
    }
}
