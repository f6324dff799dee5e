//! Thread CPU time (`CLOCK_THREAD_CPUTIME_ID`, through rustix's safe `clock_gettime`) as a
//! criterion measurement.
//!
//! The development machine has 2 cores shared with other engineers' builds (load averages of
//! 5–10): wall-clock time then includes the time the bench thread waits for a core, several times
//! its own running time. The thread's CPU time counts only the time it runs (still slowed by
//! cache and memory contention, which no host measurement avoids). A syscall per reading
//! (a few hundred ns), so it is read per criterion sample, never per stage.

use std::time::Duration;

use criterion::measurement::{Measurement, ValueFormatter};
use criterion::Throughput;
use rustix::time::{clock_gettime, ClockId};

/// CPU time the calling thread has run so far.
pub fn thread_cpu() -> Duration {
    let t = clock_gettime(ClockId::ThreadCPUTime);
    Duration::new(
        u64::try_from(t.tv_sec).unwrap_or(0),
        u32::try_from(t.tv_nsec).unwrap_or(0),
    )
}

/// Whether a span of `wall` wall-clock time during which the thread ran `cpu` was spent running
/// (not waiting for a core): `wall ≤ cpu + 1 % + 5 µs`.
pub fn ran_throughout(wall: Duration, cpu: Duration) -> bool {
    wall <= cpu + cpu / 100 + Duration::from_micros(5)
}

/// The criterion set-up of the tracker and scaling benches: thread CPU time, 10 samples, 0.5 s
/// warm-up, 2 s of measurement.
pub fn criterion() -> criterion::Criterion<ThreadCpuTime> {
    criterion::Criterion::default()
        .with_measurement(ThreadCpuTime)
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2))
}

/// Criterion measurement: the bench thread's CPU time.
#[derive(Debug, Clone, Copy, Default)]
pub struct ThreadCpuTime;

/// Formats nanoseconds like criterion's wall-time formatter.
#[derive(Debug, Clone, Copy, Default)]
pub struct NsFormatter;

impl ValueFormatter for NsFormatter {
    fn scale_values(&self, ns: f64, values: &mut [f64]) -> &'static str {
        let (factor, unit) = if ns < 1e3 {
            (1.0, "ns")
        } else if ns < 1e6 {
            (1e-3, "µs")
        } else if ns < 1e9 {
            (1e-6, "ms")
        } else {
            (1e-9, "s")
        };
        for v in values {
            *v *= factor;
        }
        unit
    }

    fn scale_throughputs(
        &self,
        _typical: f64,
        _throughput: &Throughput,
        _values: &mut [f64],
    ) -> &'static str {
        "(no throughput)"
    }

    fn scale_for_machines(&self, _values: &mut [f64]) -> &'static str {
        "ns"
    }
}

impl Measurement for ThreadCpuTime {
    type Intermediate = Duration;
    type Value = Duration;

    fn start(&self) -> Duration {
        thread_cpu()
    }

    fn end(&self, i: Duration) -> Duration {
        thread_cpu().saturating_sub(i)
    }

    fn add(&self, v1: &Duration, v2: &Duration) -> Duration {
        *v1 + *v2
    }

    fn zero(&self) -> Duration {
        Duration::ZERO
    }

    fn to_f64(&self, value: &Duration) -> f64 {
        value.as_nanos() as f64
    }

    fn formatter(&self) -> &dyn ValueFormatter {
        &NsFormatter
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_time_advances_while_running() {
        let t0 = thread_cpu();
        let mut x = 0u64;
        for i in 0..2_000_000u64 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(i));
        }
        assert!(thread_cpu() > t0, "{x}");
    }

    #[test]
    fn sleeping_is_not_running() {
        let w0 = std::time::Instant::now();
        let c0 = thread_cpu();
        std::thread::sleep(Duration::from_millis(20));
        assert!(!ran_throughout(w0.elapsed(), thread_cpu() - c0));
    }
}
