//! Stage probes for the host: a timer that charges the wall-clock time between two
//! [`Probe::enter`] calls to the stage entered first, and a probe that only counts the calls
//! (to measure what the probe mechanism itself costs).

use std::time::{Duration, Instant};

use stjpdacf::probe::{Probe, Stage};

/// Accumulates `std::time::Instant` time per stage (one `Instant::now()` per call).
#[derive(Debug, Clone)]
pub struct StageTimer {
    acc: [Duration; Stage::COUNT],
    current: Option<Stage>,
    since: Instant,
    calls: u64,
}

impl Default for StageTimer {
    fn default() -> Self {
        Self::new()
    }
}

impl StageTimer {
    /// A timer with nothing charged.
    pub fn new() -> Self {
        Self {
            acc: [Duration::ZERO; Stage::COUNT],
            current: None,
            since: Instant::now(),
            calls: 0,
        }
    }

    /// Time charged to `stage` so far.
    pub fn get(&self, stage: Stage) -> Duration {
        self.acc[stage as usize]
    }

    /// Time charged to every stage, indexed by `Stage as usize`.
    pub fn all(&self) -> &[Duration; Stage::COUNT] {
        &self.acc
    }

    /// Calls received.
    pub fn calls(&self) -> u64 {
        self.calls
    }

    /// Forgets what was charged.
    pub fn reset(&mut self) {
        self.acc = [Duration::ZERO; Stage::COUNT];
        self.current = None;
        self.calls = 0;
    }
}

impl Probe for StageTimer {
    #[inline]
    fn enter(&mut self, stage: Stage) {
        let now = Instant::now();
        if let Some(c) = self.current {
            self.acc[c as usize] += now.duration_since(self.since);
        }
        self.current = (stage != Stage::Done).then_some(stage);
        self.since = now;
        self.calls += 1;
    }
}

/// Counts calls per stage, nothing else.
#[derive(Debug, Clone, Default)]
pub struct CallCounter {
    /// Calls per stage, indexed by `Stage as usize`.
    pub calls: [u64; Stage::COUNT],
}

impl CallCounter {
    /// All calls.
    pub fn total(&self) -> u64 {
        self.calls.iter().sum()
    }
}

impl Probe for CallCounter {
    #[inline]
    fn enter(&mut self, stage: Stage) {
        self.calls[stage as usize] += 1;
    }
}

/// Stages grouped as the reports show them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StageGroup {
    /// Binning … Backward (the spatial JPDACF of the frame).
    Spatial,
    /// Lane identity.
    Identity,
    /// The temporal coupled filter.
    Temporal,
    /// The fixed-lag smoother's window.
    Smoother,
    /// Output assembly.
    Output,
    /// The known lanes' association against their prediction (docs/design.md §11).
    Known,
}

impl StageGroup {
    /// Every group, in pipeline order.
    pub const ALL: [StageGroup; 6] = [
        StageGroup::Spatial,
        StageGroup::Identity,
        StageGroup::Temporal,
        StageGroup::Smoother,
        StageGroup::Output,
        StageGroup::Known,
    ];

    /// Lower-case name.
    pub const fn name(self) -> &'static str {
        match self {
            StageGroup::Spatial => "spatial",
            StageGroup::Identity => "identity",
            StageGroup::Temporal => "temporal",
            StageGroup::Smoother => "smoother",
            StageGroup::Output => "output",
            StageGroup::Known => "known",
        }
    }

    /// Whether `stage` belongs to this group.
    pub fn contains(self, stage: Stage) -> bool {
        match self {
            StageGroup::Spatial => stage <= Stage::Backward,
            StageGroup::Identity => stage == Stage::Identity,
            StageGroup::Temporal => stage == Stage::Temporal,
            StageGroup::Smoother => stage == Stage::Smoother,
            StageGroup::Output => stage == Stage::Output,
            StageGroup::Known => stage == Stage::Known,
        }
    }

    /// Time charged to the group's stages.
    pub fn of(self, timer: &StageTimer) -> Duration {
        Stage::ALL
            .iter()
            .filter(|s| self.contains(**s))
            .map(|s| timer.get(*s))
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timer_charges_the_stage_entered_first() {
        let mut t = StageTimer::new();
        t.enter(Stage::Binning);
        std::thread::sleep(Duration::from_millis(2));
        t.enter(Stage::Identity);
        t.enter(Stage::Done);
        t.enter(Stage::Output); // nothing charged after Done until the next call
        assert!(t.get(Stage::Binning) >= Duration::from_millis(2));
        assert_eq!(t.get(Stage::Done), Duration::ZERO);
        assert_eq!(t.get(Stage::Output), Duration::ZERO);
        assert_eq!(t.calls(), 4);
        assert_eq!(
            StageGroup::Spatial.of(&t),
            t.get(Stage::Binning),
            "binning is spatial"
        );
    }

    #[test]
    fn groups_partition_the_stages_before_done() {
        for s in Stage::ALL {
            let n = StageGroup::ALL.iter().filter(|g| g.contains(s)).count();
            assert_eq!(n, usize::from(s != Stage::Done), "{s:?}");
        }
    }
}
