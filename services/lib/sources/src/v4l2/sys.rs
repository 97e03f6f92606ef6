//! The part of the kernel's V4L2 interface (`<linux/videodev2.h>`) a capture needs, written out
//! from the header's layout: the structures as `repr(C)`, the ioctl request numbers, the flags.
//! The kernel's user-space ABI is stable, so these do not change with the kernel; their sizes
//! are checked at compile time against the header's (x86-64 and aarch64 alike: every field is
//! fixed-width except the pointer-sized union in `Buffer`), and the whole is exercised against
//! the kernel's own `vivid` driver (`tests/vivid.rs`).
//!
//! No bindgen: the default build reads cameras without libclang.

#![allow(dead_code)]

use std::os::raw::c_ulong;

const IOC_WRITE: c_ulong = 1;
const IOC_READ: c_ulong = 2;

const fn ioc(dir: c_ulong, nr: c_ulong, size: usize) -> c_ulong {
    (dir << 30) | ((size as c_ulong) << 16) | ((b'V' as c_ulong) << 8) | nr
}
const fn ior<T>(nr: c_ulong) -> c_ulong {
    ioc(IOC_READ, nr, std::mem::size_of::<T>())
}
const fn iow<T>(nr: c_ulong) -> c_ulong {
    ioc(IOC_WRITE, nr, std::mem::size_of::<T>())
}
const fn iowr<T>(nr: c_ulong) -> c_ulong {
    ioc(IOC_READ | IOC_WRITE, nr, std::mem::size_of::<T>())
}

pub const VIDIOC_QUERYCAP: c_ulong = ior::<Capability>(0);
pub const VIDIOC_ENUM_FMT: c_ulong = iowr::<FmtDesc>(2);
pub const VIDIOC_G_FMT: c_ulong = iowr::<Format>(4);
pub const VIDIOC_S_FMT: c_ulong = iowr::<Format>(5);
pub const VIDIOC_REQBUFS: c_ulong = iowr::<RequestBuffers>(8);
pub const VIDIOC_QUERYBUF: c_ulong = iowr::<Buffer>(9);
pub const VIDIOC_QBUF: c_ulong = iowr::<Buffer>(15);
pub const VIDIOC_DQBUF: c_ulong = iowr::<Buffer>(17);
pub const VIDIOC_STREAMON: c_ulong = iow::<i32>(18);
pub const VIDIOC_STREAMOFF: c_ulong = iow::<i32>(19);
pub const VIDIOC_G_PARM: c_ulong = iowr::<StreamParm>(21);
pub const VIDIOC_S_PARM: c_ulong = iowr::<StreamParm>(22);
pub const VIDIOC_G_CTRL: c_ulong = iowr::<Control>(27);
pub const VIDIOC_S_CTRL: c_ulong = iowr::<Control>(28);
pub const VIDIOC_QUERYCTRL: c_ulong = iowr::<QueryCtrl>(36);
pub const VIDIOC_QUERYMENU: c_ulong = iowr::<QueryMenu>(37);

pub const BUF_TYPE_VIDEO_CAPTURE: u32 = 1;
pub const MEMORY_MMAP: u32 = 1;
pub const FIELD_NONE: u32 = 1;

pub const CAP_VIDEO_CAPTURE: u32 = 0x0000_0001;
pub const CAP_STREAMING: u32 = 0x0400_0000;
pub const CAP_DEVICE_CAPS: u32 = 0x8000_0000;

pub const BUF_FLAG_ERROR: u32 = 0x0000_0040;
pub const BUF_FLAG_TIMESTAMP_MASK: u32 = 0x0000_e000;
pub const BUF_FLAG_TIMESTAMP_MONOTONIC: u32 = 0x0000_2000;
pub const BUF_FLAG_TSTAMP_SRC_MASK: u32 = 0x0007_0000;
pub const BUF_FLAG_TSTAMP_SRC_SOE: u32 = 0x0001_0000;

pub const CTRL_FLAG_DISABLED: u32 = 0x0001;
pub const CTRL_FLAG_NEXT_CTRL: u32 = 0x8000_0000;
pub const CTRL_TYPE_MENU: u32 = 3;
pub const CTRL_TYPE_CTRL_CLASS: u32 = 6;

pub const CID_GAIN: u32 = 0x0098_0913;
pub const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
pub const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
pub const CID_TEST_PATTERN: u32 = 0x009f_0903;
pub const EXPOSURE_MANUAL: i32 = 1;

#[repr(C)]
#[derive(Clone, Copy)]
pub struct Capability {
    pub driver: [u8; 16],
    pub card: [u8; 32],
    pub bus_info: [u8; 32],
    pub version: u32,
    pub capabilities: u32,
    pub device_caps: u32,
    pub reserved: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct FmtDesc {
    pub index: u32,
    pub type_: u32,
    pub flags: u32,
    pub description: [u8; 32],
    pub pixelformat: u32,
    pub mbus_code: u32,
    pub reserved: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct PixFormat {
    pub width: u32,
    pub height: u32,
    pub pixelformat: u32,
    pub field: u32,
    pub bytesperline: u32,
    pub sizeimage: u32,
    pub colorspace: u32,
    pub priv_: u32,
    pub flags: u32,
    pub ycbcr_enc: u32,
    pub quantization: u32,
    pub xfer_func: u32,
}

/// `struct v4l2_format`: the union is 200 bytes and 8-aligned (some members hold pointers).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct Format {
    pub type_: u32,
    pub fmt: FormatUnion,
}

#[repr(C)]
#[derive(Clone, Copy)]
pub union FormatUnion {
    pub pix: PixFormat,
    pub raw: [u8; 200],
    pub align: [u64; 25],
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct RequestBuffers {
    pub count: u32,
    pub type_: u32,
    pub memory: u32,
    pub capabilities: u32,
    pub flags: u8,
    pub reserved: [u8; 3],
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct Timecode {
    pub type_: u32,
    pub flags: u32,
    pub frames: u8,
    pub seconds: u8,
    pub minutes: u8,
    pub hours: u8,
    pub userbits: [u8; 4],
}

#[repr(C)]
#[derive(Clone, Copy)]
pub union BufferM {
    pub offset: u32,
    pub userptr: c_ulong,
    pub fd: i32,
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct Buffer {
    pub index: u32,
    pub type_: u32,
    pub bytesused: u32,
    pub flags: u32,
    pub field: u32,
    pub timestamp: libc::timeval,
    pub timecode: Timecode,
    pub sequence: u32,
    pub memory: u32,
    pub m: BufferM,
    pub length: u32,
    pub reserved2: u32,
    pub request_fd: i32,
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct Fract {
    pub numerator: u32,
    pub denominator: u32,
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct CaptureParm {
    pub capability: u32,
    pub capturemode: u32,
    pub timeperframe: Fract,
    pub extendedmode: u32,
    pub readbuffers: u32,
    pub reserved: [u32; 4],
}

#[repr(C)]
#[derive(Clone, Copy)]
pub union StreamParmUnion {
    pub capture: CaptureParm,
    pub raw: [u8; 200],
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct StreamParm {
    pub type_: u32,
    pub parm: StreamParmUnion,
}

pub const CAP_TIMEPERFRAME: u32 = 0x1000;

#[repr(C)]
#[derive(Clone, Copy)]
pub struct Control {
    pub id: u32,
    pub value: i32,
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct QueryCtrl {
    pub id: u32,
    pub type_: u32,
    pub name: [u8; 32],
    pub minimum: i32,
    pub maximum: i32,
    pub step: i32,
    pub default_value: i32,
    pub flags: u32,
    pub reserved: [u32; 2],
}

/// `struct v4l2_querymenu`: packed in the header, 44 bytes.
#[repr(C, packed)]
#[derive(Clone, Copy)]
pub struct QueryMenu {
    pub id: u32,
    pub index: u32,
    pub name: [u8; 32],
    pub reserved: u32,
}

// The header's sizes on 64-bit Linux (checked with gcc against <linux/videodev2.h>, 6.1).
#[cfg(target_pointer_width = "64")]
const _: () = {
    assert!(std::mem::size_of::<Capability>() == 104);
    assert!(std::mem::size_of::<FmtDesc>() == 64);
    assert!(std::mem::size_of::<PixFormat>() == 48);
    assert!(std::mem::size_of::<Format>() == 208);
    assert!(std::mem::size_of::<RequestBuffers>() == 20);
    assert!(std::mem::size_of::<Buffer>() == 88);
    assert!(std::mem::offset_of!(Buffer, timestamp) == 24);
    assert!(std::mem::offset_of!(Buffer, sequence) == 56);
    assert!(std::mem::offset_of!(Buffer, m) == 64);
    assert!(std::mem::size_of::<StreamParm>() == 204);
    assert!(std::mem::size_of::<Control>() == 8);
    assert!(std::mem::size_of::<QueryCtrl>() == 68);
    assert!(std::mem::size_of::<QueryMenu>() == 44);
    assert!(VIDIOC_QUERYCAP == 0x8068_5600);
    assert!(VIDIOC_S_FMT == 0xc0d0_5605);
    assert!(VIDIOC_DQBUF == 0xc058_5611);
    assert!(VIDIOC_STREAMON == 0x4004_5612);
    assert!(VIDIOC_S_PARM == 0xc0cc_5616);
    assert!(VIDIOC_QUERYCTRL == 0xc044_5624);
};

/// A four-character code as the kernel stores it.
pub fn fourcc(code: &[u8; 4]) -> u32 {
    u32::from_le_bytes(*code)
}

/// A four-character code in letters ("YUYV", "Y16 ").
pub fn fourcc_str(code: u32) -> String {
    code.to_le_bytes()
        .iter()
        .map(|&b| {
            if b.is_ascii_graphic() || b == b' ' {
                b as char
            } else {
                '?'
            }
        })
        .collect()
}

/// A NUL-terminated name from the driver.
pub fn c_name(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

/// All zero: every V4L2 structure starts so.
pub fn zeroed<T: Copy>() -> T {
    // SAFETY: only used with the plain-data structures above, for which all-zero bytes are a
    // valid value (integers, byte arrays and unions of them).
    unsafe { std::mem::zeroed() }
}
