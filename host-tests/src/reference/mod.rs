//! The f64 reference implementation, written straight from `DESIGN.md` with dynamic nalgebra
//! matrices. It shares no code with the core (`stjpdacf`) and is the oracle the core is tested
//! against; it is itself checked against the golden values of independent implementations
//! (GPy, scipy, filterpy, Stone Soup) in `host-tests/tests/`.

pub mod identity;
pub mod jpda;
pub mod pipeline;
pub mod spatial;
pub mod statespace;
pub mod temporal;
