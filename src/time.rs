//! Time stamps of frames. The core never reads a clock: the caller stamps each frame.

/// A point in time, integer microseconds (the core never reads a clock).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Instant(i64);

impl Instant {
    /// From microseconds.
    pub const fn from_micros(us: i64) -> Self {
        Self(us)
    }
    /// From milliseconds.
    pub const fn from_millis(ms: i64) -> Self {
        Self(ms.saturating_mul(1000))
    }
    /// Microseconds.
    pub const fn as_micros(self) -> i64 {
        self.0
    }
}
