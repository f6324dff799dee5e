//! Track management of the spatial filter (`docs/spatial-filter.md`): initiation from consistent
//! points with a B-conditioned prior, confirmation, ending and merging.

use super::*;

impl<const NS: usize, const LANES: usize, const ROWS: usize, const PER_ROW: usize>
    SpatialFilter<NS, LANES, ROWS, PER_ROW>
{
    /// §3.2: start tentative tracks from consistent free points; returns the mask of the row's
    /// points that started a track.
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    pub(super) fn initiate<const NT: usize, const POINTS: usize>(
        &mut self,
        r: usize,
        pts: &[f32; PER_ROW],
        m: usize,
        init_rows: usize,
        cfg: &Config,
        params: &RowParams,
        hv: &SVector<f32, NS>,
        tables: &Tables<NT, LANES, POINTS>,
        rep: &mut SpatialReport,
    ) -> u32 {
        // Free points (valid for no active track), sorted by x. Each active track's predicted
        // measurement and its variance, once.
        let mut pred = [(0.0f32, f32::INFINITY); LANES];
        let mut np = 0usize;
        for (t, mt) in self.meta.iter().enumerate().take(self.state.len()) {
            if mt.status != Status::Ended {
                set(&mut pred, np, self.predicted_z(t, hv, params.r));
                np += 1;
            }
        }
        let pred = pred.get(..np).unwrap_or(&[]);
        let mut free = [(0.0f32, 0u8); PER_ROW];
        let mut nf = 0usize;
        for (j, x) in pts.iter().enumerate().take(m) {
            let valid_for_some = pred.iter().any(|(z, s)| {
                let e = x - z;
                e * e / s <= params.gamma
            });
            if !valid_for_some {
                set(&mut free, nf, (*x, j as u8));
                nf += 1;
            }
        }
        if let Some(f) = free.get_mut(..nf) {
            // By x; ties keep input order (a stable sort).
            crate::linalg::sort_by(f, |a, b| a.0.total_cmp(&b.0).is_lt());
        }
        let mut used = 0u32;
        let slot = r % MAX_INIT_ROWS;
        let mut keep = [0.0f32; PER_ROW];
        let mut nk = 0usize;
        for (x, j) in free.iter().take(nf).copied() {
            let consistent = (1..=init_rows).any(|back| {
                if back > r {
                    return false;
                }
                let b = (r - back) % MAX_INIT_ROWS;
                let n = usize::from(get(&self.buf_n, b));
                self.buf
                    .get(b)
                    .is_some_and(|row| row.iter().take(n).any(|y| (x - y).abs() <= cfg.init_gate))
            });
            let tentative = self
                .meta
                .iter()
                .take(self.state.len())
                .filter(|mt| mt.status == Status::Tentative)
                .count();
            if consistent && tentative < usize::from(cfg.max_tentative) && self.state.len() < LANES
            {
                if self.start_track(r, x, hv, params.r, tables) {
                    rep.started += 1;
                    used |= 1 << j;
                    continue;
                }
            } else if consistent {
                rep.no_slot += 1;
            }
            set(&mut keep, nk, x);
            nk += 1;
        }
        if let Some(b) = self.buf.get_mut(slot) {
            *b = keep;
        }
        set(&mut self.buf_n, slot, nk as u8);
        used
    }

    /// §3.2d: the B-conditioned prior of a new track at lateral position `x`, inserted at its rank.
    fn start_track<const NT: usize, const POINTS: usize>(
        &mut self,
        r: usize,
        x: f32,
        hv: &SVector<f32, NS>,
        meas_var: f32,
        tables: &Tables<NT, LANES, POINTS>,
    ) -> bool {
        let n = self.state.len();
        let k = (0..n)
            .filter(|&t| self.predicted_z(t, hv, 0.0).0 < x)
            .count();
        // Row k of Λ = B_{n+1}⁻¹ from the stored Cholesky factor: L v = e_k, Lᵀ y = v.
        let m = n + 1;
        let l = &tables.coreg_chol;
        let lg = |i: usize, j: usize| l.get((i, j)).copied().unwrap_or(0.0);
        let mut v = [0.0f32; LANES];
        for i in 0..m {
            let mut s = if i == k { 1.0 } else { 0.0 };
            for j in 0..i {
                s -= lg(i, j) * get(&v, j);
            }
            set(&mut v, i, s / lg(i, i));
        }
        let mut y = [0.0f32; LANES];
        for i in (0..m).rev() {
            let mut s = get(&v, i);
            for j in i + 1..m {
                s -= lg(j, i) * get(&y, j);
            }
            set(&mut y, i, s / lg(i, i));
        }
        let lkk = get(&y, k);
        if !(lkk.is_finite() && lkk > 0.0) {
            return false;
        }
        // a_i over the existing ranks (old rank i ↔ new slot i or i + 1).
        let mut a = [0.0f32; LANES];
        for i in 0..n {
            let slot = if i < k { i } else { i + 1 };
            set(&mut a, i, -get(&y, slot) / lkk);
        }
        // S zeroes the offset row: x_new = [c; Σ a_i g_i + w].
        let sel = SMatrix::<f32, NS, NS>::from_fn(|i, j| if i == j && i > 0 { 1.0 } else { 0.0 });
        let mut mean = SVector::<f32, NS>::zeros();
        let mut cross = [SMatrix::<f32, NS, NS>::zeros(); LANES];
        for i in 0..n {
            let ai = get(&a, i);
            if let Some(xi) = self.state.mean(i) {
                mean += sel * xi * ai;
            }
            for (j, c) in cross.iter_mut().enumerate().take(n) {
                if let Some(pij) = self.state.cov(i, j) {
                    *c += sel * pij * ai;
                }
            }
        }
        let mut var = SMatrix::<f32, NS, NS>::zeros();
        for i in 0..n {
            for j in 0..n {
                if let Some(pij) = self.state.cov(i, j) {
                    var += sel * pij * sel * (get(&a, i) * get(&a, j));
                }
            }
        }
        let pinf = &tables.spatial.model.p_inf;
        var += SMatrix::<f32, NS, NS>::from_fn(|i, j| match (i, j) {
            (0, 0) => tables.hyper.offset_variance,
            (0, _) | (_, 0) => 0.0,
            _ => pinf.get((i - 1, j - 1)).copied().unwrap_or(0.0) / lkk,
        });
        if let Some(c0) = mean.get_mut(0) {
            *c0 = x;
        }
        let used = self
            .meta
            .iter()
            .take(n)
            .fold(0u32, |acc, mt| acc | (1 << mt.store));
        let store = (0..LANES as u32)
            .find(|s| used & (1 << s) == 0)
            .unwrap_or(0) as u8;
        if self.state.insert(k, mean, &var, &cross).is_err() {
            return false;
        }
        // Shift metadata right of k.
        for i in (k + 1..=n).rev() {
            let prev = get(&self.meta, i - 1);
            set(&mut self.meta, i, prev);
        }
        set(
            &mut self.meta,
            k,
            Meta {
                store,
                start_row: r as u16,
                last_rec: r as u16,
                ..Meta::EMPTY
            },
        );
        for mt in self.meta.iter_mut().take(n + 1) {
            mt.near = 0;
        }
        // Condition on the initiating point (a certain association).
        self.state.update_single(k, hv, x, meas_var);
        true
    }

    /// §3.4–3.5: hits and misses, confirm / delete / end, merge.
    #[inline(never)]
    pub(super) fn manage(
        &mut self,
        r: usize,
        o: &row::RowOutcome<LANES>,
        cfg: &Config,
        hv: &SVector<f32, NS>,
        params: &RowParams,
        rep: &mut SpatialReport,
    ) {
        let n = self.state.len();
        let mut delete = 0u32;
        for t in 0..n {
            let Some(mt) = self.meta.get_mut(t) else {
                continue;
            };
            if mt.status == Status::Ended || o.failed {
                continue;
            }
            let lr = 1.0 - BIRTH_PD * params.pg
                + BIRTH_PD * get(&o.dens, t) / params.clutter_density.max(1e-6);
            if lr.is_finite() && lr > 0.0 {
                mt.llr += crate::math::ln(lr);
            }
            if 1.0 - get(&o.beta_miss, t) >= 0.5 {
                mt.llr_last = mt.llr;
                mt.hits = mt.hits.saturating_add(1);
                mt.miss_run = 0;
                if mt.first_row == NO_ROW {
                    mt.first_row = r as u16;
                }
                mt.last_row = r as u16;
                if mt.status == Status::Tentative && mt.hits >= cfg.confirm_hits {
                    mt.status = Status::Confirmed;
                    rep.confirmed += 1;
                }
            } else {
                mt.misses = mt.misses.saturating_add(1);
                mt.miss_run = mt.miss_run.saturating_add(1);
                match mt.status {
                    Status::Tentative
                        if mt.miss_run
                            >= if mt.hits > 0 {
                                cfg.tentative_gap_misses
                            } else {
                                cfg.tentative_misses
                            } =>
                    {
                        delete |= 1 << t;
                    }
                    Status::Confirmed if mt.miss_run >= cfg.max_misses => {
                        mt.status = Status::Ended;
                        rep.ended += 1;
                    }
                    _ => {}
                }
            }
        }
        // Merge adjacent near-duplicates.
        for t in 0..n.saturating_sub(1) {
            let (ma, mb) = (get(&self.meta, t), get(&self.meta, t + 1));
            if ma.status == Status::Ended || mb.status == Status::Ended || delete & (3 << t) != 0 {
                continue;
            }
            let (za, _) = self.predicted_z(t, hv, params.r);
            let (zb, _) = self.predicted_z(t + 1, hv, params.r);
            let near = if (za - zb).abs() <= cfg.merge_distance {
                ma.near.saturating_add(1)
            } else {
                0
            };
            if let Some(mt) = self.meta.get_mut(t) {
                mt.near = near;
            }
            if near >= cfg.merge_rows {
                let loser =
                    if ma.hits < mb.hits || (ma.hits == mb.hits && ma.start_row > mb.start_row) {
                        t
                    } else {
                        t + 1
                    };
                delete |= 1 << loser;
                rep.merged += 1;
            }
        }
        for t in (0..n).rev() {
            if delete & (1 << t) != 0 {
                if get(&self.meta, t).status == Status::Tentative {
                    rep.deleted += 1;
                }
                self.remove_track(t);
            }
        }
    }

    fn remove_track(&mut self, t: usize) {
        let n = self.state.len();
        self.state.remove(t);
        for i in t..n.saturating_sub(1) {
            let next = get(&self.meta, i + 1);
            set(&mut self.meta, i, next);
        }
        for mt in self.meta.iter_mut() {
            mt.near = 0;
        }
    }
}
