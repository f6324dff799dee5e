//! The board example under QEMU mps2-an386 (Cortex-M4F): the SPI front end is emulated from a
//! host file of wire-format frames (`target/frames.stjf`, read through semihosting; every
//! chip-select window reads the current frame from its first byte, as the wire protocol says,
//! and a window longer than the header moves the front end to its next frame); the lanes go
//! out on the CMSDK UART0 (QEMU `-serial file:target/lanes.stjl`). Prints a summary line and
//! exits QEMU when the file is exhausted.
#![no_std]
#![no_main]

use core::cell::RefCell;

use cortex_m::interrupt::Mutex;
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln, nr, syscall};
use defmt_rtt as _;
use embedded_hal::spi::{self, Operation, SpiDevice};
use panic_semihosting as _;
use stjpdacf::wire::HEADER_LEN;
use stjpdacf_board::{Board, Polled};

/// The board (tracker, receiver, buffers): a static, never on the stack; all zero until `main`
/// initialises it in place, so it is in `.bss`.
static BOARD: Mutex<RefCell<Board>> = Mutex::new(RefCell::new(Board::UNINIT));

/// The host file the SPI side reads (NUL-terminated for semihosting).
const FRAMES: &[u8] = b"target/frames.stjf\0";

/// SPI errors of the emulated front end.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FileSpiError {
    /// No frame left.
    End,
    /// The host file could not be read.
    Io,
}

impl spi::Error for FileSpiError {
    fn kind(&self) -> spi::ErrorKind {
        spi::ErrorKind::Other
    }
}

/// A front end replaying a host file of frames.
struct FileSpi {
    handle: usize,
    frame_at: usize,
}

impl FileSpi {
    fn open(path: &[u8]) -> Option<Self> {
        // SAFETY: semihosting SYS_OPEN with a NUL-terminated path, mode 0 ("r"), and the path's
        // length without the NUL; the debugger (QEMU) only reads the path.
        let h = unsafe { syscall!(OPEN, path.as_ptr(), nr::open::R, path.len() - 1) };
        (h as isize >= 0).then_some(Self {
            handle: h,
            frame_at: 0,
        })
    }

    /// Reads `buf.len()` bytes at `at`; false at the end of the file or on error.
    fn read_at(&self, at: usize, buf: &mut [u8]) -> Result<(), FileSpiError> {
        // SAFETY: semihosting SYS_SEEK on an open handle (QEMU only changes its file offset).
        if unsafe { syscall!(SEEK, self.handle, at) } != 0 {
            return Err(FileSpiError::Io);
        }
        // SAFETY: semihosting SYS_READ into `buf`, which is valid for `buf.len()` writes; it
        // returns the number of bytes *not* read.
        let left = unsafe { syscall!(READ, self.handle, buf.as_mut_ptr(), buf.len()) };
        if left == 0 {
            Ok(())
        } else {
            Err(FileSpiError::End)
        }
    }
}

impl spi::ErrorType for FileSpi {
    type Error = FileSpiError;
}

impl SpiDevice for FileSpi {
    fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), FileSpiError> {
        let mut n = 0usize;
        for op in ops {
            if let Operation::Read(buf) = op {
                self.read_at(self.frame_at + n, buf)?;
                n += buf.len();
            }
        }
        if n > HEADER_LEN {
            self.frame_at += n;
        }
        Ok(())
    }
}

/// The CMSDK APB UART0 of mps2-an386 (transmit only).
struct Uart {
    base: usize,
}

impl Uart {
    const DATA: usize = 0x00;
    const STATE: usize = 0x04;
    const CTRL: usize = 0x08;
    const BAUDDIV: usize = 0x10;

    /// Enables the transmitter (the baud divisor must be ≥ 16 on this UART).
    fn new(base: usize) -> Self {
        let u = Self { base };
        u.write_reg(Self::BAUDDIV, 16);
        u.write_reg(Self::CTRL, 1);
        u
    }

    fn write_reg(&self, off: usize, v: u32) {
        // SAFETY: a register of the UART block at `base` (mps2-an386 memory map), word-aligned.
        unsafe { core::ptr::write_volatile((self.base + off) as *mut u32, v) }
    }

    fn read_reg(&self, off: usize) -> u32 {
        // SAFETY: as `write_reg`.
        unsafe { core::ptr::read_volatile((self.base + off) as *const u32) }
    }
}

impl embedded_io::ErrorType for Uart {
    type Error = core::convert::Infallible;
}

impl embedded_io::Write for Uart {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        for &b in buf {
            while self.read_reg(Self::STATE) & 1 != 0 {}
            self.write_reg(Self::DATA, u32::from(b));
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

#[entry]
fn main() -> ! {
    let ok = cortex_m::interrupt::free(|cs| {
        let mut board = BOARD.borrow(cs).borrow_mut();
        board.init();
        let Some(mut spi) = FileSpi::open(FRAMES) else {
            hprintln!("ERROR cannot open target/frames.stjf");
            return false;
        };
        let mut uart = Uart::new(0x4000_4000);
        let (mut frames, mut lanes) = (0u32, 0usize);
        loop {
            match board.poll(&mut spi, &mut uart) {
                Ok(Polled::Tracked { lanes: n, .. }) => {
                    frames += 1;
                    lanes += n;
                }
                Ok(Polled::Rejected | Polled::Refused) => {}
                Err(stjpdacf_board::BoardError::Spi(FileSpiError::End)) => break,
                Err(_) => {
                    hprintln!("ERROR SPI or UART failure");
                    return false;
                }
            }
        }
        let stats = board.receiver().stats();
        // The end of the file shows as one failed SPI read: not a bad frame.
        hprintln!(
            "BOARD frames={} lanes={} bad_frames={} skipped={}",
            frames,
            lanes,
            stats.rejected().saturating_sub(stats.spi_errors),
            stats.skipped
        );
        true
    });
    debug::exit(if ok {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
    loop {
        cortex_m::asm::nop();
    }
}
