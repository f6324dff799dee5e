//! Flat-road pinhole inverse perspective mapping (IPM) between image pixels and the bird's-eye view
//! (docs/design.md §4.0, §8).
//!
//! The camera looks straight down the road (no roll, no yaw; the principal column is the vanishing
//! point's column) from height `h` above a flat road. An image point (col, row) below the horizon
//! row `v_y` maps to
//!
//! * `u = f·h / (row − v_y)` metres ahead of the camera, and
//! * `x = (col − c_x)·h / (row − v_y)` metres to the right of the camera axis,
//!
//! and back by `row = v_y + f·h/u`, `col = c_x + f·x/u`. The focal length `f` (pixels) is not
//! observable from lane geometry: it only rescales `u` (lateral distances do not depend on it).
//! The TuSimple preset assumes `f = 1000 px`; every value in BEV metres (length-scales, the
//! window) is stated for that choice.

use serde::{Deserialize, Serialize};

/// A flat-road pinhole camera, enough to map image pixels to BEV metres and back.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    /// Image width, pixels.
    pub width: f64,
    /// Image height, pixels.
    pub height: f64,
    /// Column of the vanishing point (= principal column), pixels.
    pub vp_col: f64,
    /// Row of the vanishing point (the horizon), pixels.
    pub vp_row: f64,
    /// Camera height above the road, metres.
    pub height_m: f64,
    /// Focal length, pixels (assumed; it only rescales `u`).
    pub focal_px: f64,
}

impl Camera {
    /// TuSimple 1280×720: vanishing point (654, 238.5) px, camera height 1.67 m (fitted to the
    /// 3.7 m lane spacing), assumed focal length 1000 px.
    pub fn tusimple() -> Self {
        Self {
            width: 1280.0,
            height: 720.0,
            vp_col: 654.0,
            vp_row: 238.5,
            height_m: 1.67,
            focal_px: 1000.0,
        }
    }

    /// A guess for an uncalibrated `width`×`height` camera: the vanishing point at the image's
    /// centre column and 0.4 of its height, camera height 1.5 m (a car), focal length 0.8 ×
    /// width (a 64° horizontal field of view). Meant to be refined from the image
    /// ([`crate::frontend::estimate_vanishing_point`]); the height only scales lateral metres
    /// (a 20 % error makes a 3.7 m lane 3.0 or 4.4 m) and the focal length only longitudinal
    /// ones.
    pub fn guess(width: f64, height: f64) -> Self {
        Self {
            width,
            height,
            vp_col: 0.5 * width,
            vp_row: 0.4 * height,
            height_m: 1.5,
            focal_px: 0.8 * width,
        }
    }

    /// A CULane-style 1640×590 camera: [`Camera::guess`] at that size (CULane publishes no
    /// calibration; estimate the horizon from the images).
    pub fn culane() -> Self {
        Self::guess(1640.0, 590.0)
    }

    /// The same camera for an image resized by `s` (e.g. 0.4 for the 512×288 TuSimple sample):
    /// every pixel quantity is scaled, so BEV coordinates are unchanged.
    pub fn scaled(&self, s: f64) -> Self {
        Self {
            width: self.width * s,
            height: self.height * s,
            vp_col: self.vp_col * s,
            vp_row: self.vp_row * s,
            height_m: self.height_m,
            focal_px: self.focal_px * s,
        }
    }

    /// Image (col, row) → BEV (u, x) in metres; `None` at or above the horizon row, or for
    /// non-finite input.
    pub fn to_bev(&self, col: f64, row: f64) -> Option<(f64, f64)> {
        let dr = row - self.vp_row;
        if !(dr.is_finite() && dr > 0.0 && col.is_finite()) {
            return None;
        }
        let scale = self.height_m / dr;
        Some((self.focal_px * scale, (col - self.vp_col) * scale))
    }

    /// BEV (u, x) in metres → image (col, row); `None` unless `u > 0` and both are finite.
    pub fn to_image(&self, u: f64, x: f64) -> Option<(f64, f64)> {
        if !(u.is_finite() && u > 0.0 && x.is_finite()) {
            return None;
        }
        Some((
            self.vp_col + self.focal_px * x / u,
            self.vp_row + self.focal_px * self.height_m / u,
        ))
    }

    /// The image row seen at `u` metres ahead (`None` unless `u > 0`).
    pub fn row_at(&self, u: f64) -> Option<f64> {
        self.to_image(u, 0.0).map(|(_, r)| r)
    }

    /// The median of `cams`, quantity by quantity (horizon row, vanishing column, height, focal
    /// length; the mean of the middle two for an even count), with the first camera's image
    /// size: one camera from estimates of a fixed camera, which single estimates that missed do
    /// not move. `None` if `cams` is empty.
    pub fn median(cams: &[Camera]) -> Option<Camera> {
        let first = cams.first()?;
        let median = |field: fn(&Camera) -> f64| {
            let mut v: Vec<f64> = cams.iter().map(field).collect();
            v.sort_by(f64::total_cmp);
            let m = v.len() / 2;
            if v.len() % 2 == 1 {
                v[m]
            } else {
                0.5 * (v[m - 1] + v[m])
            }
        };
        Some(Camera {
            vp_row: median(|c| c.vp_row),
            vp_col: median(|c| c.vp_col),
            height_m: median(|c| c.height_m),
            focal_px: median(|c| c.focal_px),
            ..*first
        })
    }
}

impl Camera {
    /// A camera from a command-line value: `tusimple` ([`Camera::tusimple`]), `culane`
    /// ([`Camera::culane`]) or the path of a
    /// JSON file with the fields of [`Camera`] (`width`, `height`, `vp_col`, `vp_row`,
    /// `height_m`, `focal_px`), valid ([`Camera::check`]), its horizon above the image's
    /// bottom row and its vanishing column within the image.
    pub fn from_spec(spec: &str) -> anyhow::Result<Self> {
        use anyhow::Context;
        if spec == "tusimple" {
            return Ok(Self::tusimple());
        }
        if spec == "culane" {
            return Ok(Self::culane());
        }
        let text = std::fs::read_to_string(spec).with_context(|| {
            format!("reading camera file {spec} (or use `tusimple` or `culane`)")
        })?;
        let cam: Camera =
            serde_json::from_str(&text).with_context(|| format!("{spec}: malformed camera"))?;
        cam.check().map_err(|e| anyhow::anyhow!("{spec}: {e}"))?;
        // A calibration (unlike a frame's estimate, which may miss) sees the road: a horizon at
        // or below the bottom row leaves no image row that does. The mapping has no yaw, so the
        // vanishing column is the principal point's and lies in the image. A horizon above the
        // image is a camera pitched down, and allowed.
        anyhow::ensure!(
            cam.vp_row < cam.height && (0.0..=cam.width).contains(&cam.vp_col),
            "{spec}: the vanishing point ({}, {}) must lie above the bottom row of the {}x{} \
             image (the horizon; no row sees the road otherwise) and within its columns",
            cam.vp_col,
            cam.vp_row,
            cam.width,
            cam.height
        );
        Ok(cam)
    }

    /// Checks the values: image size, camera height and focal length positive and finite, the
    /// vanishing point finite (a camera file's, or a frame's [`crate::tusimple::Frame::camera`]).
    pub fn check(&self) -> anyhow::Result<()> {
        let positive = |v: f64| v > 0.0 && v.is_finite();
        anyhow::ensure!(
            positive(self.width)
                && positive(self.height)
                && positive(self.height_m)
                && positive(self.focal_px)
                && self.vp_col.is_finite()
                && self.vp_row.is_finite(),
            "camera sizes, height and focal length must be positive and finite, the vanishing \
             point finite: {self:?}"
        );
        Ok(())
    }
}

impl Default for Camera {
    fn default() -> Self {
        Self::tusimple()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_full_and_scaled() {
        for cam in [Camera::tusimple(), Camera::tusimple().scaled(0.4)] {
            for &(c, r) in &[
                (0.0, 719.0),
                (640.0, 300.0),
                (1279.0, 250.0),
                (100.0, 239.0),
            ] {
                let (c, r) = (c * cam.width / 1280.0, r * cam.height / 720.0);
                let (u, x) = cam.to_bev(c, r).unwrap();
                let (c2, r2) = cam.to_image(u, x).unwrap();
                assert!(
                    (c2 - c).abs() < 1e-9 && (r2 - r).abs() < 1e-9,
                    "{c},{r} -> {c2},{r2}"
                );
            }
        }
        assert!(Camera::tusimple().to_bev(600.0, 238.5).is_none());
        assert!(Camera::tusimple().to_bev(600.0, 100.0).is_none());
        assert!(Camera::tusimple().to_image(0.0, 1.0).is_none());
    }

    #[test]
    fn scaling_keeps_bev() {
        let full = Camera::tusimple();
        let small = full.scaled(0.4);
        let (u1, x1) = full.to_bev(900.0, 400.0).unwrap();
        let (u2, x2) = small.to_bev(360.0, 160.0).unwrap();
        assert!((u1 - u2).abs() < 1e-12 && (x1 - x2).abs() < 1e-12);
    }

    /// x of a labelled lane at BEV distance `u`, interpolating linearly between label rows.
    fn lane_x_at(cam: &Camera, h: &[f64], xs: &[f64], u: f64) -> f64 {
        let pts: Vec<(f64, f64)> = h
            .iter()
            .zip(xs)
            .filter(|(_, &x)| x >= 0.0)
            .filter_map(|(&r, &c)| cam.to_bev(c, r))
            .collect();
        for w in pts.windows(2) {
            let ((ua, xa), (ub, xb)) = (w[0], w[1]);
            if (ua.min(ub)..=ua.max(ub)).contains(&u) {
                return xa + (xb - xa) * (u - ua) / (ub - ua);
            }
        }
        panic!("u = {u} not covered");
    }

    #[test]
    fn tusimple_lanes_parallel_and_3_7_m_apart() {
        // Three real frames of TuSimple's train set (label_data_0313.json: clips/0313-1/6040,
        // clips/0313-1/23700, clips/0313-1/39720), the two lanes that bound the ego lane,
        // label rows 280..=710 copied verbatim.
        let h: Vec<f64> = (0..44).map(|i| 280.0 + 10.0 * i as f64).collect();
        let cam = Camera::tusimple();
        for (left, right) in [
            (&F6040[0], &F6040[1]),
            (&F23700[0], &F23700[1]),
            (&F39720[0], &F39720[1]),
        ] {
            let widths: Vec<f64> = [10.0, 15.0, 20.0, 25.0, 30.0]
                .iter()
                .map(|&u| lane_x_at(&cam, &h, right, u) - lane_x_at(&cam, &h, left, u))
                .collect();
            let (lo, hi) = widths
                .iter()
                .fold((f64::MAX, f64::MIN), |(a, b), &w| (a.min(w), b.max(w)));
            assert!(lo > 3.4 && hi < 4.0, "lane width {widths:?} not ~3.7 m");
            assert!(hi - lo < 0.15, "lanes not parallel: widths {widths:?}");
        }
    }

    const F6040: [[f64; 44]; 2] = [
        [
            632., 625., 617., 609., 601., 594., 586., 578., 570., 563., 555., 547., 539., 532.,
            524., 516., 508., 501., 493., 485., 477., 469., 462., 454., 446., 438., 431., 423.,
            415., 407., 400., 392., 384., 376., 369., 361., 353., 345., 338., 330., 322., 314.,
            307., 299.,
        ],
        [
            719., 734., 748., 762., 777., 791., 805., 820., 834., 848., 863., 877., 891., 906.,
            920., 934., 949., 963., 978., 992., 1006., 1021., 1035., 1049., 1064., 1078., 1092.,
            1107., 1121., 1135., 1150., 1164., 1178., 1193., 1207., 1221., 1236., 1250., 1265.,
            -2., -2., -2., -2., -2.,
        ],
    ];
    const F23700: [[f64; 44]; 2] = [
        [
            522., 505., 489., 473., 456., 440., 424., 407., 391., 375., 359., 342., 326., 310.,
            293., 277., 261., 244., 228., 212., 196., 179., 163., 147., 130., 114., 98., 81., 65.,
            49., 33., 16., -2., -2., -2., -2., -2., -2., -2., -2., -2., -2., -2., -2.,
        ],
        [
            611., 616., 621., 625., 630., 635., 640., 645., 650., 655., 660., 665., 670., 675.,
            680., 684., 689., 694., 699., 704., 709., 714., 719., 724., 729., 734., 738., 743.,
            748., 753., 758., 763., 768., 773., 778., 783., 788., 793., 797., 802., 807., 812.,
            817., 822.,
        ],
    ];
    const F39720: [[f64; 44]; 2] = [
        [
            607., 599., 590., 580., 571., 562., 553., 543., 534., 525., 516., 506., 497., 488.,
            479., 470., 460., 451., 442., 433., 423., 414., 405., 396., 386., 377., 368., 359.,
            349., 340., 331., 322., 312., 303., 294., 285., 276., 266., 257., 248., 239., 229.,
            220., 211.,
        ],
        [
            699., 713., 726., 739., 752., 764., 777., 790., 803., 816., 829., 841., 854., 867.,
            880., 893., 906., 918., 931., 944., 957., 970., 982., 995., 1008., 1021., 1034., 1047.,
            1059., 1072., 1085., 1098., 1111., 1124., 1136., 1149., 1162., 1175., 1188., 1201.,
            1213., 1226., 1239., 1252.,
        ],
    ];
}
