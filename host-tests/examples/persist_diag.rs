//! Diagnostics of the known-lane stage on the replay: per published lane whether it matches a
//! ground-truth lane (official rule), bucketed by existence, age and hits; missed lanes.
//! `cargo run --release -p stjpdacf-test-support --example persist_diag -- [low|mid|high] [round1]`
use std::collections::HashMap;

use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::metric::{lane_angle, lane_threshold, line_accuracy, PT_THRESH};
use stjpdacf_tools::synth::{self, NoiseLevel, SynthParams};
use stjpdacf_tools::track::{self, FrameView, Space, MAX_REPORT_MISSES};
use stjpdacf_tools::tusimple;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let level = match args.get(1).map(String::as_str) {
        Some("low") => NoiseLevel::Low,
        Some("high") => NoiseLevel::High,
        _ => NoiseLevel::Mid,
    };
    let mut cfg = if args.iter().any(|a| a == "round1") {
        TrackerConfig::ROUND1
    } else {
        TrackerConfig::DEFAULT
    };
    let envf = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<f32>().ok());
    if let Some(v) = envf("QMEM") {
        cfg.persist.q_memory = v;
    }
    if let Some(v) = envf("CONFIRM") {
        cfg.persist.confirm_hits = v as u16;
    }
    if let Some(v) = envf("PBIRTH") {
        cfg.persist.p_birth = v;
    }
    let labels = tusimple::read_labels(
        &stjpdacf_tools::repo_root().join("data/tusimple/train_subset.json"),
    )?;
    let cam = Camera::tusimple();
    let mut params = SynthParams::preset(level);
    if let Ok(v) = std::env::var("CL") {
        params.clutter_rate = v.parse()?;
    }
    if std::env::var("NOD").is_ok() {
        params.shadows = 0.0;
        params.cars = 0.0;
        params.road_edge_prob = 0.0;
    }
    if std::env::var("STATIC").is_ok() {
        params.motion = 0.0;
        params.lane_change_prob = 0.0;
        params.merge_prob = 0.0;
        params.far_end_prob = 0.0;
    }
    if let Ok(v) = std::env::var("PD") {
        params.detect_prob = v.parse()?;
    }
    let o = synth::synthesize(&labels, &params, &cam, 1)?;
    let gt: HashMap<String, &tusimple::TuSimpleRecord> =
        o.gt_all.iter().map(|g| (g.raw_file.clone(), g)).collect();
    // (matched, existence bucket) counts; age buckets.
    let mut fp_by_ex = [0usize; 10];
    let mut tp_by_ex = [0usize; 10];
    let mut fp_by_age = [0usize; 6];
    let mut tp_by_age = [0usize; 6];
    let mut fn_total = 0usize;
    let mut gt_total = 0usize;
    let mut frames = 0usize;
    let mut new_lanes = 0usize;
    let mut prev_ids: Vec<u32> = Vec::new();
    let mut fn_covered = 0usize;
    let mut fp_best = [0usize; 4];
    let mut fp_dup = 0usize;
    let mut qs: Vec<f32> = Vec::new();
    let mut fp_class = [0usize; 4];
    let mut fp_dist: Vec<f64> = Vec::new();
    // For FP lanes with best acc in [0.3, 0.85): gt rows where pred missing / off near / off far / ok.
    let mut rows_cat = [0usize; 4];
    let bands = [3.0, 6.0, 10.0, 20.0, 40.0, 80.0];
    let mut berr = [(0.0f64, 0.0f64, 0usize); 5];
    let mut vpred = [(0.0f64, 0usize); 5];
    let mut abs_err: Vec<Vec<f64>> = vec![Vec::new(); 5];
    let dump = std::env::var("DUMP").ok();
    let mut age_err: Vec<Vec<f64>> = vec![Vec::new(); 4];
    let mut t = stjpdacf::tables::DEFAULT.clone();
    let env = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<f32>().ok());
    if let Some(l) = env("TL") {
        t.temporal.kernel.lengthscale = l;
        let lam = 3f32.sqrt() / l;
        t.temporal.p_inf[(1, 1)] = lam * lam * t.temporal.kernel.variance;
        t.hyper.frame_step = -1.0;
    }
    if let Some(m) = env("MN") {
        t.hyper.meas_noise = m;
    }
    let t: &'static stjpdacf::tables::ReferenceTables = Box::leak(Box::new(t));
    track::track_with(&o.frames, t, &cam, Space::Image, cfg, |v: FrameView<'_>| {
        let (Some(out), Some(pred)) = (v.output, v.prediction) else {
            return;
        };
        let Some(g) = gt.get(pred.raw_file.as_str()) else {
            return;
        };
        frames += 1;
        qs.push(
            v.tracker.persist().last_nis_ratio
                + 1000.0 * f32::from(v.tracker.persist().lanes[0].passes.min(9)),
        );
        let pub_lanes: Vec<_> = out
            .filtered
            .iter()
            .filter(|l| l.misses <= MAX_REPORT_MISSES)
            .collect();
        let ids: Vec<u32> = pub_lanes.iter().map(|l| l.id.0).collect();
        if v.index > 0 && o.frames[v.index - 1].clip == v.frame.clip {
            new_lanes += ids.iter().filter(|i| !prev_ids.contains(i)).count();
        }
        prev_ids = ids;
        let ys = &g.h_samples;
        if dump.as_deref() == Some(v.frame.clip.as_str()) {
            let r = &out.report;
            for l in out.filtered.iter() {
                let mut near: Vec<String> = Vec::new();
                for p in v.points.iter().filter(|p| p[0] < 12.0) {
                    if let Some((xp, _)) = v.tracker.lane_at(l.slot as usize, p[0]) {
                        if (p[1] - xp).abs() < 1.0 {
                            near.push(format!("{:.1}:{:+.2}", p[0], p[1] - xp));
                        }
                    }
                }
                println!("   slot {} near pts (u:dx) {}", l.slot, near.join(" "));
            }
            if v.index == 65 {
                let mut gts: Vec<Vec<(f64, f64)>> = Vec::new();
                for lane in &g.lanes {
                    gts.push(
                        lane.iter()
                            .zip(g.h_samples.iter())
                            .filter(|(x, _)| **x >= 0.0)
                            .filter_map(|(x, y)| cam.to_bev(*x, *y))
                            .collect(),
                    );
                }
                for gl in &gts {
                    let pts: Vec<(f64, f64)> = gl
                        .iter()
                        .copied()
                        .filter(|(u, _)| *u >= 3.0 && *u <= 80.0)
                        .collect();
                    if pts.len() < 5 {
                        continue;
                    }
                    let mut jm = nalgebra::DMatrix::<f64>::zeros(7, 7);
                    let mut iv = nalgebra::DVector::<f64>::zeros(7);
                    let cs: Vec<[f32; 7]> = pts
                        .iter()
                        .map(|(u, _)| {
                            stjpdacf::persist::row_basis::<2, 6, 16, 7>(
                                &stjpdacf::tables::DEFAULT,
                                *u as f32,
                                7,
                            )
                            .0
                        })
                        .collect();
                    for ((_, x), c) in pts.iter().zip(&cs) {
                        for j in 0..7 {
                            iv[j] += f64::from(c[j]) * x;
                            for k in 0..7 {
                                jm[(j, k)] += f64::from(c[j]) * f64::from(c[k]);
                            }
                        }
                    }
                    for j in 0..7 {
                        jm[(j, j)] += 1e-6;
                    }
                    let a = jm.clone().lu().solve(&iv).unwrap();
                    let res: Vec<String> = pts
                        .iter()
                        .zip(&cs)
                        .map(|((u, x), c)| {
                            let f: f64 = (0..7).map(|j| f64::from(c[j]) * a[j]).sum();
                            format!("{:.0}:{:+.3}", u, f - x)
                        })
                        .collect();
                    println!("   GP fit residuals: {}", res.join(" "));
                }
                for p in v.points.iter().filter(|p| p[0] < 10.0) {
                    let near: Vec<String> = gts
                        .iter()
                        .enumerate()
                        .filter_map(|(k, gl)| {
                            // gt x at u by nearest
                            let q = gl.iter().min_by(|a, b| {
                                (a.0 - f64::from(p[0]))
                                    .abs()
                                    .total_cmp(&(b.0 - f64::from(p[0])).abs())
                            })?;
                            if (q.0 - f64::from(p[0])).abs() < 0.7 {
                                Some(format!("g{}@{:.2}:{:+.3}", k, q.0, f64::from(p[1]) - q.1))
                            } else {
                                None
                            }
                        })
                        .collect();
                    println!("   pt u {:.2} x {:+.3} | {}", p[0], p[1], near.join(" "));
                }
            }
            let pr = v.tracker.persist();
            let act: Vec<String> = (0..6)
                .filter_map(|sl| {
                    v.tracker.lane_at(sl, 10.0).map(|(x, _)| {
                        format!(
                            "s{} x10 {:+.2} ex {:.3} pd {:?}",
                            sl,
                            x,
                            pr.lanes[sl].existence,
                            (0..16)
                                .map(|b| (pr.lanes[sl].pd(b) * 10.0) as i32)
                                .collect::<Vec<_>>()
                        )
                    })
                })
                .collect();
            println!("  active: {}", act.join(" | "));
            println!(
                "  span: {:?}",
                pr.span
                    .iter()
                    .map(|s| ((s[0] * 10.0).round() / 10.0, (s[1] * 10.0).round() / 10.0))
                    .collect::<Vec<_>>()
            );
            println!(
                "  noise sd per band: {:?}",
                (0..16)
                    .map(|b| (pr.noise(b, 0.01).sqrt() * 1000.0) as i32)
                    .collect::<Vec<_>>()
            );
            println!(
                "  clutter per band: {:?}",
                (0..16)
                    .map(|b| (pr.clutter(b, 0.05, 0.005) * 1000.0) as i32)
                    .collect::<Vec<_>>()
            );
            println!("frame {}: spatial lanes_out {} started {} | identity matched {} new {} | lanes {:?}", v.index, r.spatial.lanes_out, r.spatial.started, r.identity.matched, r.identity.started, out.filtered.iter().map(|l| (l.slot, l.id.0, (l.existence * 100.0) as i32, l.hits)).collect::<Vec<_>>());
        }
        for lane in &g.lanes {
            let pts: Vec<(f64, f64)> = lane
                .iter()
                .zip(ys.iter())
                .filter(|(x, _)| **x >= 0.0)
                .filter_map(|(x, y)| cam.to_bev(*x, *y))
                .filter(|(u, _)| *u >= 3.0 && *u <= 80.0)
                .collect();
            if pts.len() < 3 {
                continue;
            }
            let mut best: Option<(f64, usize)> = None;
            for l in &pub_lanes {
                let mut e = 0.0;
                let mut n = 0;
                for (u, x) in &pts {
                    if let Some((xp, _)) = v.tracker.lane_at(l.slot as usize, *u as f32) {
                        e += (f64::from(xp) - x).abs();
                        n += 1;
                    }
                }
                if n > 0 {
                    let m = e / n as f64;
                    if best.is_none_or(|b| m < b.0) {
                        best = Some((m, l.slot as usize));
                    }
                }
            }
            if let (Some(dc), Some((_, slot))) = (&dump, best) {
                if &v.frame.clip == dc {
                    let s: Vec<String> = pts
                        .iter()
                        .step_by(4)
                        .map(|(u, x)| {
                            format!(
                                "u{:.0}:{:+.2}",
                                u,
                                v.tracker
                                    .lane_at(slot, *u as f32)
                                    .map_or(f64::NAN, |(xp, _)| f64::from(xp) - x)
                            )
                        })
                        .collect();
                    println!(
                        "{} slot {} x@gt0 {:.2}: {}",
                        v.index,
                        slot,
                        pts[0].1,
                        s.join(" ")
                    );
                }
            }
            if let Some((m, slot)) = best {
                if m < 1.0 {
                    for (u, x) in &pts {
                        if let Some((xp, var)) = v.tracker.lane_at(slot, *u as f32) {
                            let b = bands
                                .windows(2)
                                .position(|w| *u >= w[0] && *u < w[1])
                                .unwrap_or(4);
                            let d = f64::from(xp) - x;
                            berr[b].0 += d;
                            berr[b].1 += d * d;
                            berr[b].2 += 1;
                            vpred[b].0 += f64::from(var);
                            vpred[b].1 += 1;
                            abs_err[b].push(d.abs());
                            if b == 0 {
                                let age = pub_lanes
                                    .iter()
                                    .find(|l| l.slot as usize == slot)
                                    .map_or(0, |l| l.age);
                                age_err[match age {
                                    0 => 0,
                                    1..=2 => 1,
                                    3..=5 => 2,
                                    _ => 3,
                                }]
                                .push(d.abs());
                            }
                        }
                    }
                }
            }
        }
        let gl: Vec<&Vec<f64>> = g
            .lanes
            .iter()
            .filter(|l| l.iter().any(|x| *x >= 0.0))
            .collect();
        gt_total += gl.len();
        let mut gmatched = vec![false; gl.len()];
        for (k, pl) in pred.lanes.iter().enumerate() {
            let mut m = false;
            for (gi, x) in gl.iter().enumerate() {
                let th = lane_threshold(lane_angle(x, ys));
                if line_accuracy(pl, x, th) >= PT_THRESH {
                    m = true;
                    gmatched[gi] = true;
                }
            }
            let l = pub_lanes.get(k);
            let ex = l.map_or(0.0, |l| l.existence);
            let b = ((ex * 10.0) as usize).min(9);
            let age = l.map_or(0, |l| l.age) as usize;
            let ab = match age {
                0 => 0,
                1 => 1,
                2..=3 => 2,
                4..=7 => 3,
                8..=15 => 4,
                _ => 5,
            };
            if m {
                tp_by_ex[b] += 1;
                tp_by_age[ab] += 1;
            } else {
                fp_by_ex[b] += 1;
                fp_by_age[ab] += 1;
                let mut best = 0.0;
                let mut bi = 0;
                for (gi, x) in gl.iter().enumerate() {
                    let th = lane_threshold(lane_angle(x, ys));
                    let a = line_accuracy(pl, x, th);
                    if a > best {
                        best = a;
                        bi = gi;
                    }
                }
                if let Some(l) = l {
                    // mean |Δx| to the nearest gt lane over common u in [3, 40]
                    let mut bestd = f64::INFINITY;
                    for x in &gl {
                        let gb: Vec<(f64, f64)> = x
                            .iter()
                            .zip(ys.iter())
                            .filter(|(x, _)| **x >= 0.0)
                            .filter_map(|(x, y)| cam.to_bev(*x, *y))
                            .filter(|p| p.0 >= 3.0 && p.0 <= 40.0)
                            .collect();
                        let ds: Vec<f64> = gb
                            .iter()
                            .filter_map(|(u, x)| {
                                v.tracker
                                    .lane_at(l.slot as usize, *u as f32)
                                    .map(|(xp, _)| (f64::from(xp) - x).abs())
                            })
                            .collect();
                        if ds.len() >= 3 {
                            bestd = bestd.min(ds.iter().sum::<f64>() / ds.len() as f64);
                        }
                    }
                    fp_class[if bestd < 0.3 {
                        0
                    } else if bestd < 2.0 {
                        1
                    } else if bestd.is_finite() {
                        2
                    } else {
                        3
                    }] += 1;
                }
                fp_best[if best < 0.1 {
                    0
                } else if best < 0.3 {
                    1
                } else if best < 0.6 {
                    2
                } else {
                    3
                }] += 1;
                if best >= 0.3 {
                    let th = lane_threshold(lane_angle(gl[bi], ys));
                    if let Some((k2, _)) = pred
                        .lanes
                        .iter()
                        .enumerate()
                        .find(|(k2, p2)| *k2 != k && line_accuracy(p2, gl[bi], th) >= PT_THRESH)
                    {
                        fp_dup += 1;
                        if std::env::var("ROWDUMP").is_ok() && fp_dup % 25 == 0 {
                            let th = lane_threshold(lane_angle(gl[bi], ys));
                            let pat: String = pl
                                .iter()
                                .zip(gl[bi].iter())
                                .map(|(p, g)| {
                                    if *g < 0.0 {
                                        if *p < 0.0 {
                                            '_'
                                        } else {
                                            'E'
                                        }
                                    } else if *p < 0.0 {
                                        'm'
                                    } else if (p - g).abs() < th {
                                        '.'
                                    } else if (p - g).abs() < 2.0 * th {
                                        'x'
                                    } else {
                                        'X'
                                    }
                                })
                                .collect();
                            let pat2: String = pred.lanes[k2]
                                .iter()
                                .zip(gl[bi].iter())
                                .map(|(p, g)| {
                                    if *g < 0.0 {
                                        if *p < 0.0 {
                                            '_'
                                        } else {
                                            'E'
                                        }
                                    } else if *p < 0.0 {
                                        'm'
                                    } else if (p - g).abs() < th {
                                        '.'
                                    } else if (p - g).abs() < 2.0 * th {
                                        'x'
                                    } else {
                                        'X'
                                    }
                                })
                                .collect();
                            println!(
                                "ROW {} f{} FP  [{}] acc {:.2}",
                                v.frame.clip, v.index, pat, best
                            );
                            println!("ROW {} f{} TP  [{}]", v.frame.clip, v.index, pat2);
                        }
                        if std::env::var("DUPDUMP").is_ok() && fp_dup % 25 == 0 {
                            if let (Some(a), Some(b)) = (l, pub_lanes.get(k2)) {
                                let us = [4.0f32, 8.0, 13.0, 18.0, 23.0, 33.0, 43.0, 60.0];
                                let row = |l: &stjpdacf::tracker::LaneEstimate<16>| {
                                    us.iter()
                                        .map(|u| {
                                            v.tracker
                                                .lane_at(l.slot as usize, *u)
                                                .map_or("-".to_string(), |(x, var)| {
                                                    format!("{:+.2}±{:.2}", x, var.sqrt())
                                                })
                                        })
                                        .collect::<Vec<_>>()
                                        .join(" ")
                                };
                                println!(
                                    "DUP {} f{}: FP id {} age {} ex {:.2} ext {:.0}-{:.0}: {}",
                                    v.frame.clip,
                                    v.index,
                                    a.id.0,
                                    a.age,
                                    a.existence,
                                    a.u_first,
                                    a.u_last,
                                    row(a)
                                );
                                println!(
                                    "    matched id {} age {} ex {:.2} ext {:.0}-{:.0}: {}",
                                    b.id.0,
                                    b.age,
                                    b.existence,
                                    b.u_first,
                                    b.u_last,
                                    row(b)
                                );
                                let gtb: Vec<(f64, f64)> = gl[bi]
                                    .iter()
                                    .zip(ys.iter())
                                    .filter(|(x, _)| **x >= 0.0)
                                    .filter_map(|(x, y)| cam.to_bev(*x, *y))
                                    .collect();
                                println!(
                                    "    gt: {}",
                                    us.iter()
                                        .map(|u| gtb
                                            .iter()
                                            .min_by(|p, q| (p.0 - f64::from(*u))
                                                .abs()
                                                .total_cmp(&(q.0 - f64::from(*u)).abs()))
                                            .map_or("-".to_string(), |p| {
                                                if (p.0 - f64::from(*u)).abs() < 2.0 {
                                                    format!("{:+.2}", p.1)
                                                } else {
                                                    "-".into()
                                                }
                                            }))
                                        .collect::<Vec<_>>()
                                        .join(" ")
                                );
                            }
                        }
                    }
                }
                if let Some(l) = l {
                    if let Some((x0, _)) = v.tracker.lane_at(l.slot as usize, 10.0) {
                        let d = pub_lanes
                            .iter()
                            .filter(|o| o.slot != l.slot)
                            .filter_map(|o| v.tracker.lane_at(o.slot as usize, 10.0))
                            .map(|(x, _)| f64::from((x - x0).abs()))
                            .fold(f64::INFINITY, f64::min);
                        fp_dist.push(d);
                    }
                }
                if best >= 0.3 {
                    let x = gl[bi];
                    let th = lane_threshold(lane_angle(x, ys));
                    for (k, (&p, &gx)) in pl.iter().zip(x.iter()).enumerate() {
                        if gx < 0.0 {
                            continue;
                        }
                        if p < 0.0 {
                            rows_cat[0] += 1;
                        } else if (p - gx).abs() >= th {
                            if ys[k] > 400.0 {
                                rows_cat[1] += 1
                            } else {
                                rows_cat[2] += 1
                            }
                        } else {
                            rows_cat[3] += 1;
                        }
                    }
                }
            }
        }
        for (gi, x) in gl.iter().enumerate() {
            if !gmatched[gi] {
                fn_total += 1;
                if std::env::var("FNDUMP").is_ok() {
                    let bev: Vec<(f64, f64)> = x
                        .iter()
                        .zip(ys.iter())
                        .filter(|(x, _)| **x >= 0.0)
                        .filter_map(|(x, y)| cam.to_bev(*x, *y))
                        .collect();
                    let th = lane_threshold(lane_angle(x, ys));
                    let best = pred
                        .lanes
                        .iter()
                        .map(|pl| line_accuracy(pl, x, th))
                        .fold(0.0, f64::max);
                    let (u0, u1) = (
                        bev.iter().map(|p| p.0).fold(f64::INFINITY, f64::min),
                        bev.iter().map(|p| p.0).fold(0.0, f64::max),
                    );
                    let x0 = bev
                        .iter()
                        .min_by(|a, b| a.0.total_cmp(&b.0))
                        .map_or(f64::NAN, |p| p.1);
                    println!("FN {} frame {} gt lane u {:.1}-{:.1} x_near {:+.2} n {} best acc {:.2} | pub {:?}", v.frame.clip, v.index, u0, u1, x0, bev.len(), best, pub_lanes.iter().map(|l| (l.id.0, (l.z[0] * 100.0).round() / 100.0, l.u_first.round(), l.u_last.round(), l.age)).collect::<Vec<_>>());
                }
                // Is some predicted lane partly on it (≥ 0.3)?
                let th = lane_threshold(lane_angle(x, ys));
                if pred.lanes.iter().any(|pl| line_accuracy(pl, x, th) >= 0.3) {
                    fn_covered += 1;
                }
            }
        }
    })?;
    println!(
        "q_scale samples: {:?}",
        qs.iter()
            .skip(13)
            .step_by(20)
            .map(|q| (q * 100.0).round() / 100.0)
            .collect::<Vec<_>>()
    );
    println!("level {level:?}, config persist={}", cfg.persist.enabled);
    println!(
        "frames {frames}, gt lanes/frame {:.2}, new published ids/frame {:.3}",
        gt_total as f64 / frames as f64,
        new_lanes as f64 / frames as f64
    );
    println!("existence bucket: TP / FP");
    for b in 0..10 {
        println!(
            "  {:.1}-{:.1}: {:5} / {:5}",
            b as f64 / 10.0,
            (b + 1) as f64 / 10.0,
            tp_by_ex[b],
            fp_by_ex[b]
        );
    }
    println!(
        "age bucket (0,1,2-3,4-7,8-15,16+): TP {:?} FP {:?}",
        tp_by_age, fp_by_age
    );
    fp_dist.sort_by(f64::total_cmp);
    println!("FP duplicates of a matched gt lane: {fp_dup}; FP distance to nearest other lane at u=10: <0.5 m {}, <1.5 m {}, <3 m {}, more {}", fp_dist.iter().filter(|d| **d < 0.5).count(), fp_dist.iter().filter(|d| **d >= 0.5 && **d < 1.5).count(), fp_dist.iter().filter(|d| **d >= 1.5 && **d < 3.0).count(), fp_dist.iter().filter(|d| **d >= 3.0).count());
    println!(
        "FP by mean BEV distance to nearest gt lane: <0.3 m {}, 0.3-2 m {}, >2 m {}, no overlap {}",
        fp_class[0], fp_class[1], fp_class[2], fp_class[3]
    );
    println!("FP best acc [<0.1, <0.3, <0.6, <0.85]: {:?}", fp_best);
    println!(
        "partial FP gt rows: pred missing {}, off near (row>400) {}, off far {}, ok {}",
        rows_cat[0], rows_cat[1], rows_cat[2], rows_cat[3]
    );
    for (b, e) in berr.iter().enumerate() {
        println!(
            "  u {:>4}-{:<4}: bias {:+.3} rms {:.3} m  (n {}), mean pred sd {:.3}",
            bands[b],
            bands[b + 1],
            e.0 / e.2 as f64,
            (e.1 / e.2 as f64).sqrt(),
            e.2,
            (vpred[b].0 / vpred[b].1 as f64).sqrt()
        );
    }
    for (b, e) in abs_err.iter_mut().enumerate() {
        e.sort_by(f64::total_cmp);
        let q = |p: f64| e[((e.len() - 1) as f64 * p) as usize];
        println!(
            "  u {:>4}: |err| median {:.3} p75 {:.3} p90 {:.3}",
            bands[b],
            q(0.5),
            q(0.75),
            q(0.9)
        );
    }
    for (b, e) in age_err.iter_mut().enumerate() {
        e.sort_by(f64::total_cmp);
        if e.is_empty() {
            continue;
        }
        let q = |p: f64| e[((e.len() - 1) as f64 * p) as usize];
        println!(
            "  age bucket {b} (0,1-2,3-5,6+): n {} median {:.3} p90 {:.3}",
            e.len(),
            q(0.5),
            q(0.9)
        );
    }
    println!(
        "FN lanes {fn_total} ({:.3}/frame), of which partly covered {fn_covered}",
        fn_total as f64 / frames as f64
    );
    Ok(())
}
