//! The kernel side of V4L2, by hand: the `#[repr(C)]` structs crossline passes to the
//! driver, the ioctl request numbers, and thin wrappers over `ioctl(2)`, `poll(2)`,
//! `mmap(2)` and `munmap(2)`. Everything `unsafe` in the capture layer is here or in a
//! `// SAFETY:`-commented block of [`super`].
//!
//! The structs mirror `include/uapi/linux/videodev2.h` (Linux 6.x; the layouts used
//! here have been stable since 3.x, fields renamed in later kernels keep their place)
//! and the request numbers follow `_IOC` in `include/uapi/asm-generic/ioctl.h`
//! (`arch/{powerpc,mips,sparc}` use the wider direction field, handled below). Only the
//! members crossline reads or writes are spelled out; the rest of each union is kept
//! as raw bytes so the size the kernel copies is right.
//!
//! ABI facts that bite:
//! - `v4l2_format.fmt` holds `struct v4l2_window`, which has pointers, so the union is
//!   pointer-aligned: `v4l2_format` is 208 bytes on 64-bit (4 + 4 padding + 200), 204
//!   on 32-bit. The request number encodes that size, so a wrong layout is `ENOTTY`.
//! - `v4l2_buffer` has a `struct timeval` (pointer-aligned) after five `u32`s and an
//!   `unsigned long`/pointer union: 88 bytes on x86_64 and aarch64.
//! - Request numbers embed `size_of` of the argument; [`Request`] computes them from
//!   the Rust type, so a request and its argument type cannot disagree.

use std::io;
use std::marker::PhantomData;
use std::mem::size_of;
use std::os::fd::{AsRawFd, BorrowedFd};
use std::ptr::NonNull;
use std::time::Duration;

use libc::c_ulong;

// --- _IOC -----------------------------------------------------------------------------

#[cfg(not(any(
    target_arch = "powerpc",
    target_arch = "powerpc64",
    target_arch = "mips",
    target_arch = "mips64",
    target_arch = "sparc",
    target_arch = "sparc64"
)))]
mod ioc {
    pub const SIZEBITS: u32 = 14;
    pub const WRITE: u32 = 1;
    pub const READ: u32 = 2;
}
#[cfg(any(
    target_arch = "powerpc",
    target_arch = "powerpc64",
    target_arch = "mips",
    target_arch = "mips64",
    target_arch = "sparc",
    target_arch = "sparc64"
))]
mod ioc {
    pub const SIZEBITS: u32 = 13;
    pub const WRITE: u32 = 4;
    pub const READ: u32 = 2;
}

const NRSHIFT: u32 = 0;
const TYPESHIFT: u32 = 8;
const SIZESHIFT: u32 = 16;
const DIRSHIFT: u32 = SIZESHIFT + ioc::SIZEBITS;

/// An ioctl request number tied to the type of its argument.
pub struct Request<T> {
    pub code: u32,
    pub name: &'static str,
    arg: PhantomData<fn() -> T>,
}

impl<T> Clone for Request<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Request<T> {}

/// `_IOC(dir, 'V', nr, sizeof(T))`.
const fn v4l2_ioc<T>(dir: u32, nr: u32, name: &'static str) -> Request<T> {
    let size = size_of::<T>() as u32;
    assert!(size < (1 << ioc::SIZEBITS));
    Request {
        code: (dir << DIRSHIFT)
            | ((b'V' as u32) << TYPESHIFT)
            | (nr << NRSHIFT)
            | (size << SIZESHIFT),
        name,
        arg: PhantomData,
    }
}

const R: u32 = ioc::READ;
const W: u32 = ioc::WRITE;
const RW: u32 = ioc::READ | ioc::WRITE;

pub const VIDIOC_QUERYCAP: Request<Capability> = v4l2_ioc(R, 0, "VIDIOC_QUERYCAP");
pub const VIDIOC_ENUM_FMT: Request<FmtDesc> = v4l2_ioc(RW, 2, "VIDIOC_ENUM_FMT");
pub const VIDIOC_G_FMT: Request<Format> = v4l2_ioc(RW, 4, "VIDIOC_G_FMT");
pub const VIDIOC_S_FMT: Request<Format> = v4l2_ioc(RW, 5, "VIDIOC_S_FMT");
pub const VIDIOC_REQBUFS: Request<RequestBuffers> = v4l2_ioc(RW, 8, "VIDIOC_REQBUFS");
pub const VIDIOC_QUERYBUF: Request<Buffer> = v4l2_ioc(RW, 9, "VIDIOC_QUERYBUF");
pub const VIDIOC_QBUF: Request<Buffer> = v4l2_ioc(RW, 15, "VIDIOC_QBUF");
pub const VIDIOC_DQBUF: Request<Buffer> = v4l2_ioc(RW, 17, "VIDIOC_DQBUF");
pub const VIDIOC_STREAMON: Request<libc::c_int> = v4l2_ioc(W, 18, "VIDIOC_STREAMON");
pub const VIDIOC_STREAMOFF: Request<libc::c_int> = v4l2_ioc(W, 19, "VIDIOC_STREAMOFF");
pub const VIDIOC_G_PARM: Request<StreamParm> = v4l2_ioc(RW, 21, "VIDIOC_G_PARM");
pub const VIDIOC_S_PARM: Request<StreamParm> = v4l2_ioc(RW, 22, "VIDIOC_S_PARM");
pub const VIDIOC_ENUM_FRAMESIZES: Request<FrmSizeEnum> = v4l2_ioc(RW, 74, "VIDIOC_ENUM_FRAMESIZES");
pub const VIDIOC_ENUM_FRAMEINTERVALS: Request<FrmIvalEnum> =
    v4l2_ioc(RW, 75, "VIDIOC_ENUM_FRAMEINTERVALS");

// --- constants from videodev2.h -------------------------------------------------------

pub const V4L2_CAP_VIDEO_CAPTURE: u32 = 0x0000_0001;
pub const V4L2_CAP_VIDEO_OUTPUT: u32 = 0x0000_0002;
pub const V4L2_CAP_VIDEO_CAPTURE_MPLANE: u32 = 0x0000_1000;
pub const V4L2_CAP_VIDEO_OUTPUT_MPLANE: u32 = 0x0000_2000;
pub const V4L2_CAP_VIDEO_M2M: u32 = 0x0000_8000;
pub const V4L2_CAP_META_CAPTURE: u32 = 0x0080_0000;
pub const V4L2_CAP_READWRITE: u32 = 0x0100_0000;
pub const V4L2_CAP_STREAMING: u32 = 0x0400_0000;
pub const V4L2_CAP_DEVICE_CAPS: u32 = 0x8000_0000;

pub const V4L2_BUF_TYPE_VIDEO_CAPTURE: u32 = 1;
pub const V4L2_BUF_TYPE_VIDEO_OUTPUT: u32 = 2;
pub const V4L2_MEMORY_MMAP: u32 = 1;
pub const V4L2_FIELD_NONE: u32 = 1;
pub const V4L2_COLORSPACE_SRGB: u32 = 8;
pub const V4L2_CAP_TIMEPERFRAME: u32 = 0x1000;

pub const V4L2_FMT_FLAG_COMPRESSED: u32 = 0x0001;
pub const V4L2_FMT_FLAG_EMULATED: u32 = 0x0002;

pub const V4L2_FRMSIZE_TYPE_DISCRETE: u32 = 1;
pub const V4L2_FRMSIZE_TYPE_CONTINUOUS: u32 = 2;
pub const V4L2_FRMSIZE_TYPE_STEPWISE: u32 = 3;
pub const V4L2_FRMIVAL_TYPE_DISCRETE: u32 = 1;

pub const V4L2_BUF_FLAG_ERROR: u32 = 0x0000_0040;
pub const V4L2_BUF_FLAG_TIMESTAMP_MASK: u32 = 0x0000_e000;
pub const V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC: u32 = 0x0000_2000;

// --- structs --------------------------------------------------------------------------

/// `struct v4l2_capability`, 104 bytes.
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

/// `struct v4l2_fmtdesc`, 64 bytes.
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

/// `struct v4l2_pix_format`, 48 bytes.
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

/// The `fmt` union of `struct v4l2_format`: 200 bytes, pointer-aligned because its
/// `struct v4l2_window` member holds pointers (`c_ulong` has a pointer's alignment on
/// Linux and keeps this type `Send`).
#[repr(C)]
#[derive(Clone, Copy)]
pub union FormatUnion {
    pub pix: PixFormat,
    pub raw_data: [u8; 200],
    align: [c_ulong; 0],
}

/// `struct v4l2_format`, 208 bytes on 64-bit.
#[repr(C)]
#[derive(Clone, Copy)]
pub struct Format {
    pub type_: u32,
    pub fmt: FormatUnion,
}

/// `struct v4l2_fract`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Fract {
    pub numerator: u32,
    pub denominator: u32,
}

/// `struct v4l2_captureparm`, 40 bytes.
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

/// `struct v4l2_outputparm`, 40 bytes.
#[repr(C)]
#[derive(Clone, Copy)]
pub struct OutputParm {
    pub capability: u32,
    pub outputmode: u32,
    pub timeperframe: Fract,
    pub extendedmode: u32,
    pub writebuffers: u32,
    pub reserved: [u32; 4],
}

/// The `parm` union of `struct v4l2_streamparm`, 200 bytes.
#[repr(C)]
#[derive(Clone, Copy)]
pub union StreamParmUnion {
    pub capture: CaptureParm,
    pub output: OutputParm,
    pub raw_data: [u8; 200],
}

/// `struct v4l2_streamparm`, 204 bytes.
#[repr(C)]
#[derive(Clone, Copy)]
pub struct StreamParm {
    pub type_: u32,
    pub parm: StreamParmUnion,
}

/// `struct v4l2_requestbuffers`, 20 bytes.
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

/// `struct v4l2_timecode`, 16 bytes.
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

/// The `m` union of `struct v4l2_buffer`: `offset` for MMAP; the `unsigned long
/// userptr` and `struct v4l2_plane *planes` members are one pointer-sized word.
#[repr(C)]
#[derive(Clone, Copy)]
pub union BufferM {
    pub offset: u32,
    pub userptr: c_ulong,
    pub fd: i32,
}

/// `struct v4l2_buffer`, 88 bytes on 64-bit.
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
    /// `request_fd` / `reserved`.
    pub request_fd: i32,
}

/// `struct v4l2_frmsize_discrete`.
#[repr(C)]
#[derive(Clone, Copy)]
pub struct FrmSizeDiscrete {
    pub width: u32,
    pub height: u32,
}

/// `struct v4l2_frmsize_stepwise`.
#[repr(C)]
#[derive(Clone, Copy)]
pub struct FrmSizeStepwise {
    pub min_width: u32,
    pub max_width: u32,
    pub step_width: u32,
    pub min_height: u32,
    pub max_height: u32,
    pub step_height: u32,
}

#[repr(C)]
#[derive(Clone, Copy)]
pub union FrmSizeUnion {
    pub discrete: FrmSizeDiscrete,
    pub stepwise: FrmSizeStepwise,
}

/// `struct v4l2_frmsizeenum`, 44 bytes.
#[repr(C)]
#[derive(Clone, Copy)]
pub struct FrmSizeEnum {
    pub index: u32,
    pub pixel_format: u32,
    pub type_: u32,
    pub size: FrmSizeUnion,
    pub reserved: [u32; 2],
}

/// `struct v4l2_frmival_stepwise`.
#[repr(C)]
#[derive(Clone, Copy)]
pub struct FrmIvalStepwise {
    pub min: Fract,
    pub max: Fract,
    pub step: Fract,
}

#[repr(C)]
#[derive(Clone, Copy)]
pub union FrmIvalUnion {
    pub discrete: Fract,
    pub stepwise: FrmIvalStepwise,
}

/// `struct v4l2_frmivalenum`, 52 bytes.
#[repr(C)]
#[derive(Clone, Copy)]
pub struct FrmIvalEnum {
    pub index: u32,
    pub pixel_format: u32,
    pub width: u32,
    pub height: u32,
    pub type_: u32,
    pub interval: FrmIvalUnion,
    pub reserved: [u32; 2],
}

/// Plain data: `#[repr(C)]`, `Copy`, no references, and every bit pattern (all zeros
/// in particular) is a valid value, so the kernel may write any bytes into it.
///
/// # Safety
/// Implement only for types that satisfy all of the above.
pub unsafe trait Pod: Copy {}

macro_rules! pod {
    ($($t:ty),*) => {$(
        // SAFETY: a #[repr(C)] struct or union of integers and integer arrays (and
        // `libc::timeval`, two integers): no references, no invalid bit patterns.
        unsafe impl Pod for $t {}
    )*};
}
pod!(
    Capability,
    FmtDesc,
    PixFormat,
    Format,
    Fract,
    StreamParm,
    RequestBuffers,
    Buffer,
    FrmSizeEnum,
    FrmIvalEnum,
    libc::c_int
);

/// All-zero `T`, the starting point of every V4L2 argument (the kernel requires the
/// reserved fields to be zero).
pub fn zeroed<T: Pod>() -> T {
    // SAFETY: `Pod` promises that all-zero bytes are a valid `T`.
    unsafe { std::mem::zeroed() }
}

/// `ioctl(fd, request, arg)`, retried on `EINTR`.
pub fn ioctl<T: Pod>(fd: BorrowedFd<'_>, request: Request<T>, arg: &mut T) -> io::Result<()> {
    loop {
        // SAFETY: `arg` is a live, exclusive `T` and the request number encodes
        // `size_of::<T>()` (see `v4l2_ioc`), so the kernel reads and writes within it;
        // `Pod` makes whatever it writes a valid `T`. `fd` is borrowed, hence open.
        let r = unsafe { libc::ioctl(fd.as_raw_fd(), request.code as libc::Ioctl, arg as *mut T) };
        if r != -1 {
            return Ok(());
        }
        let err = io::Error::last_os_error();
        if err.kind() != io::ErrorKind::Interrupted {
            return Err(err);
        }
    }
}

/// What `poll(2)` said about a capture fd.
#[derive(Debug, PartialEq, Eq)]
pub enum Readiness {
    Readable,
    TimedOut,
    /// A signal arrived; the caller checks its stop flag.
    Interrupted,
    /// `POLLERR`, `POLLHUP` or `POLLNVAL`: the bits of `revents`.
    Failed(i16),
}

/// Waits until `fd` is readable, for at most `timeout` (rounded up to milliseconds).
pub fn poll_readable(fd: BorrowedFd<'_>, timeout: Duration) -> io::Result<Readiness> {
    let millis = timeout.as_nanos().div_ceil(1_000_000).min(i32::MAX as u128) as i32;
    let mut pfd = libc::pollfd {
        fd: fd.as_raw_fd(),
        events: libc::POLLIN,
        revents: 0,
    };
    // SAFETY: `pfd` is one valid pollfd and we pass a count of 1.
    let r = unsafe { libc::poll(&mut pfd, 1, millis) };
    if r < 0 {
        let err = io::Error::last_os_error();
        return match err.kind() {
            io::ErrorKind::Interrupted => Ok(Readiness::Interrupted),
            _ => Err(err),
        };
    }
    if r == 0 {
        return Ok(Readiness::TimedOut);
    }
    let bad = pfd.revents & (libc::POLLERR | libc::POLLHUP | libc::POLLNVAL);
    if bad != 0 {
        return Ok(Readiness::Failed(bad));
    }
    Ok(Readiness::Readable)
}

/// One driver buffer mapped into our address space; unmapped on drop.
pub struct Mapping {
    ptr: NonNull<u8>,
    len: usize,
}

// SAFETY: the mapping is owned by exactly one `Mapping` and is plain shared memory,
// not tied to the thread that created it; moving it to another thread is fine.
unsafe impl Send for Mapping {}

impl Mapping {
    /// `mmap(NULL, len, PROT_READ | PROT_WRITE, MAP_SHARED, fd, offset)`, as V4L2
    /// prescribes for `V4L2_MEMORY_MMAP` buffers.
    pub fn new(fd: BorrowedFd<'_>, len: usize, offset: u32) -> io::Result<Mapping> {
        if len == 0 {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                "driver reported a zero-length buffer",
            ));
        }
        // SAFETY: a fresh shared mapping chosen by the kernel (NULL hint), so it
        // aliases no Rust memory; failure is checked below.
        let ptr = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                len,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_SHARED,
                fd.as_raw_fd(),
                offset as libc::off_t,
            )
        };
        if ptr == libc::MAP_FAILED {
            return Err(io::Error::last_os_error());
        }
        let ptr = NonNull::new(ptr.cast::<u8>()).ok_or_else(|| {
            io::Error::new(io::ErrorKind::InvalidData, "mmap returned a null mapping")
        })?;
        Ok(Mapping { ptr, len })
    }

    pub fn byte_len(&self) -> usize {
        self.len
    }

    /// The first `len` bytes (at most the mapping's length).
    ///
    /// # Safety
    /// The buffer must stay dequeued (owned by user space, so neither the driver nor
    /// the device writes it) for as long as the returned slice lives.
    pub unsafe fn bytes(&self, len: usize) -> &[u8] {
        // SAFETY: `ptr` is valid for reads of `self.len` bytes while `self` lives (the
        // mapping is only undone in `drop`); the caller guarantees no concurrent writer.
        unsafe { std::slice::from_raw_parts(self.ptr.as_ptr(), len.min(self.len)) }
    }
}

impl Drop for Mapping {
    fn drop(&mut self) {
        // SAFETY: `ptr`/`len` are exactly what mmap returned and no slice into the
        // mapping can outlive `self` (`bytes` borrows it).
        unsafe {
            libc::munmap(self.ptr.as_ptr().cast(), self.len);
        }
    }
}

/// A fourcc as the kernel's little-endian `u32` (`v4l2_fourcc`).
pub fn fourcc_code(fourcc: [u8; 4]) -> u32 {
    u32::from_le_bytes(fourcc)
}

/// The four characters of a kernel pixel format code.
pub fn fourcc_bytes(code: u32) -> [u8; 4] {
    code.to_le_bytes()
}

/// A NUL-terminated fixed-size kernel string.
pub fn c_string(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(all(target_os = "linux", target_arch = "x86_64"))]
    #[test]
    fn struct_sizes_and_offsets_match_the_x86_64_kernel_abi() {
        use std::mem::{align_of, offset_of};
        assert_eq!(size_of::<Capability>(), 104);
        assert_eq!(offset_of!(Capability, capabilities), 84);
        assert_eq!(offset_of!(Capability, device_caps), 88);
        assert_eq!(size_of::<FmtDesc>(), 64);
        assert_eq!(offset_of!(FmtDesc, description), 12);
        assert_eq!(offset_of!(FmtDesc, pixelformat), 44);
        assert_eq!(size_of::<PixFormat>(), 48);
        assert_eq!(offset_of!(PixFormat, bytesperline), 16);
        assert_eq!(offset_of!(PixFormat, sizeimage), 20);
        assert_eq!(size_of::<FormatUnion>(), 200);
        assert_eq!(align_of::<FormatUnion>(), 8);
        assert_eq!(size_of::<Format>(), 208);
        assert_eq!(offset_of!(Format, fmt), 8);
        assert_eq!(size_of::<CaptureParm>(), 40);
        assert_eq!(size_of::<OutputParm>(), 40);
        assert_eq!(size_of::<StreamParm>(), 204);
        assert_eq!(offset_of!(StreamParm, parm), 4);
        assert_eq!(size_of::<RequestBuffers>(), 20);
        assert_eq!(size_of::<Timecode>(), 16);
        assert_eq!(size_of::<Buffer>(), 88);
        assert_eq!(offset_of!(Buffer, field), 16);
        assert_eq!(offset_of!(Buffer, timestamp), 24);
        assert_eq!(offset_of!(Buffer, timecode), 40);
        assert_eq!(offset_of!(Buffer, sequence), 56);
        assert_eq!(offset_of!(Buffer, memory), 60);
        assert_eq!(offset_of!(Buffer, m), 64);
        assert_eq!(offset_of!(Buffer, length), 72);
        assert_eq!(offset_of!(Buffer, reserved2), 76);
        assert_eq!(offset_of!(Buffer, request_fd), 80);
        assert_eq!(size_of::<FrmSizeEnum>(), 44);
        assert_eq!(offset_of!(FrmSizeEnum, size), 12);
        assert_eq!(offset_of!(FrmSizeEnum, reserved), 36);
        assert_eq!(size_of::<FrmIvalEnum>(), 52);
        assert_eq!(offset_of!(FrmIvalEnum, interval), 20);
    }

    /// The numbers as `strace -e raw=ioctl` and the C headers give them on x86_64.
    #[cfg(all(target_os = "linux", target_arch = "x86_64"))]
    #[test]
    fn request_numbers_match_the_x86_64_kernel_headers() {
        let cases: [(u32, u32); 15] = [
            (VIDIOC_QUERYCAP.code, 0x8068_5600),
            (VIDIOC_ENUM_FMT.code, 0xc040_5602),
            (VIDIOC_G_FMT.code, 0xc0d0_5604),
            (VIDIOC_S_FMT.code, 0xc0d0_5605),
            (VIDIOC_REQBUFS.code, 0xc014_5608),
            (VIDIOC_QUERYBUF.code, 0xc058_5609),
            (VIDIOC_QBUF.code, 0xc058_560f),
            (VIDIOC_DQBUF.code, 0xc058_5611),
            (VIDIOC_STREAMON.code, 0x4004_5612),
            (VIDIOC_STREAMOFF.code, 0x4004_5613),
            (VIDIOC_G_PARM.code, 0xc0cc_5615),
            (VIDIOC_S_PARM.code, 0xc0cc_5616),
            (VIDIOC_ENUM_FRAMESIZES.code, 0xc02c_564a),
            (VIDIOC_ENUM_FRAMEINTERVALS.code, 0xc034_564b),
            // _IOC by hand for one of them: dir 3 << 30 | size 208 << 16 | 'V' << 8 | 4.
            (
                (3 << 30) | (208 << 16) | ((b'V' as u32) << 8) | 4,
                0xc0d0_5604,
            ),
        ];
        for (i, (got, want)) in cases.iter().enumerate() {
            assert_eq!(got, want, "case {i}: {got:#010x} != {want:#010x}");
        }
    }

    #[test]
    fn fourcc_codes_are_little_endian() {
        assert_eq!(fourcc_code(*b"YUYV"), 0x5659_5559);
        assert_eq!(fourcc_bytes(0x4750_4a4d), *b"MJPG");
        assert_eq!(c_string(b"vivid\0\0garbage"), "vivid");
        assert_eq!(c_string(b"full"), "full");
    }

    #[test]
    fn zeroed_arguments_are_zero() {
        let b: Buffer = zeroed();
        assert_eq!((b.index, b.sequence, b.timestamp.tv_sec), (0, 0, 0));
        let f: Format = zeroed();
        // SAFETY: reading a Pod union member of a zeroed value.
        let pix = unsafe { f.fmt.pix };
        assert_eq!(pix.width, 0);
    }
}
