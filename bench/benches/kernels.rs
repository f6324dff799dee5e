//! Cost of the run-time kernel discretisations (uneven row steps, dropped frames), f32 core next
//! to the f64 reference. `cargo bench -p stjpdacf-bench --bench kernels`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use stjpdacf::kernel::{Matern32, RbfStateSpace};
use stjpdacf::tables::DEFAULT;
use stjpdacf_reference::statespace::{Matern32 as RefMatern, RbfTaylor};

fn rbf_core<const NT: usize>(l: f64) -> RbfStateSpace<NT> {
    let r = RbfTaylor {
        variance: 1.0,
        lengthscale: l,
        order: NT,
    };
    let p = r.p_inf().unwrap_or_default();
    let a = r.a();
    RbfStateSpace {
        A: nalgebra::SMatrix::from_fn(|i, j| a[(i, j)] as f32),
        qc: r.qc() as f32,
        p_inf: nalgebra::SMatrix::from_fn(|i, j| p[(i, j)] as f32),
    }
}

fn kernels(c: &mut Criterion) {
    let m = Matern32::new(1.0, 30.0);
    let mut g = c.benchmark_group("matern32_transition");
    g.bench_function("core_f32_T=0.1s", |b| {
        b.iter(|| m.transition(black_box(0.1)))
    });
    let rm = RefMatern {
        variance: 1.0,
        lengthscale: 30.0,
    };
    g.bench_function("reference_f64_T=0.1s", |b| {
        b.iter(|| rm.transition(black_box(0.1)))
    });
    g.finish();

    let mut g = c.benchmark_group("rbf_transition_du=2.4m");
    let du = 2.0 * DEFAULT.hyper.row_step;
    g.bench_function("core_f32_order2", |b| {
        b.iter(|| DEFAULT.spatial.model.transition(black_box(du)))
    });
    let m4 = rbf_core::<4>(25.0);
    g.bench_function("core_f32_order4", |b| {
        b.iter(|| m4.transition(black_box(du)))
    });
    let m6 = rbf_core::<6>(25.0);
    g.bench_function("core_f32_order6", |b| {
        b.iter(|| m6.transition(black_box(du)))
    });
    let r2 = RbfTaylor {
        variance: 1.0,
        lengthscale: 25.0,
        order: 2,
    };
    g.bench_function("reference_f64_order2", |b| {
        b.iter(|| r2.transition(black_box(du as f64)))
    });
    g.finish();
}

criterion_group!(benches, kernels);
criterion_main!(benches);
