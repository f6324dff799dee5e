//! The f64 reference implementation of `stjpdacf`, written straight from `docs/design.md` with
//! dynamic nalgebra matrices. It shares no code with the core (`stjpdacf`) and does not depend on
//! it: it is the oracle the core is tested against (`host-tests/tests/`), and is itself checked
//! against the golden values of independent implementations (GPy, scipy, filterpy, Stone Soup).
//!
//! * [`hyper`] — the hyperparameter file (`data/hyper/*.json`);
//! * [`model`] — the model matrices it defines (design §3), which the table generator of
//!   `stjpdacf-tools` rounds into the core's static tables;
//! * [`statespace`] — the kernels and their state-space forms;
//! * [`jpda`], [`spatial`] — the spatial JPDA/JPDACF row step and the frame walk (§4.1);
//! * [`temporal`] — the temporal coupled filter, RTS and fixed-lag smoother (§4.2, §5);
//! * [`identity`] — lane identity across frames;
//! * [`persist`] — the known-lane stage: association against the temporal prediction, row
//!   evidence in information form, existence evidence (§11.3–11.5);
//! * [`pipeline`] — the whole per-frame pipeline, the oracle for `stjpdacf::tracker`.

pub mod hyper;
pub mod identity;
pub mod jpda;
pub mod model;
pub mod persist;
pub mod pipeline;
pub mod spatial;
pub mod statespace;
pub mod temporal;
