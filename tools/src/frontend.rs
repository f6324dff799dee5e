//! The image front end (`stjpdacf frontend`, docs/design.md §1 step 1): camera image → inverse
//! perspective mapping (IPM) to a bird's-eye-view grid → colour and ridge filtering → region of
//! interest → non-maximum suppression per BEV row → parallel-lane filter → feature points,
//! written back as image pixels in the [`Frame`] format.
//!
//! # Steps and parameters ([`FrontendParams`], defaults in brackets)
//! 1. **IPM**: one BEV row per image row whose distance is inside the window
//!    `u_min..u_max` [3–80 m] (a row's distance is `f·h/(row − v_y)`), and lateral cells every
//!    `dx` [0.04 m] over `|x| ≤ x_max` [12 m]. Each cell is inverse-mapped to the image with the
//!    [`Camera`] and sampled bilinearly (RGB). Cells that fall outside the image are not road:
//!    the **region of interest** is the BEV window ∩ the image.
//! 2. **Colour**: intensity `I = grey + yellow_gain·max(0, (R+G)/2 − B)` [yellow_gain 0.5]
//!    (yellow paint is lifted to the level of white paint). A peak is kept only if its colour is
//!    white (HSV saturation ≤ `white_max_sat` [0.35]) or yellow (hue in `yellow_hue` [25°–75°] and
//!    saturation ≥ `yellow_min_sat` [0.2]).
//! 3. **Ridge filter across x** (lane markings are bright ridges 10–20 cm wide): the symmetric
//!    local-threshold (dark–light–dark) filter
//!    `R(x) = 2I(x) − I(x−τ) − I(x+τ) − |I(x−τ) − I(x+τ)|`, which responds to a bright band of
//!    width < 2τ and not to a single step edge (shadow boundaries, the road border). τ is
//!    `marking_width` [0.2 m] or `min_px` [1.5] image pixels at that distance, whichever is wider
//!    (far rows are blurred over several cells). `I` is first averaged over ±τ/4.
//!    The same filter with the polarity reversed, `D(x) = I(x−τ) + I(x+τ) − 2I(x) − |I(x−τ) −
//!    I(x+τ)|`, finds **dark ridges**: on the 0313 clips many lane boundaries are Botts' dots on
//!    a concrete-slab joint, a thin dark seam that is continuous where the dots are not.
//! 4. **Threshold, road check and NMS per BEV row**: cells with `R ≥ max(ridge_threshold [20],
//!    noise_k [1.25] · σ_row)` — σ_row = 1.4826 × the row's median |R|, a robust level of that
//!    row's texture, so the threshold adapts to contrast along the range — that are the maximum
//!    of R within ±τ, whose two flanks I(x±τ) are within `road_tolerance` \[60\] grey levels of the
//!    row's median intensity (the road surface), refined to sub-cell position by a parabola
//!    through the peak and its neighbours. Dark ridges likewise with `D ≥ max(dark_threshold
//!    [15], noise_k · σ_row)` and no colour check; a dark ridge within `dark_exclusion` [1.2 m]
//!    of a bright ridge of the same row is dropped (the shadow or seam beside a painted line).
//! 5. **Continuity** (off by default, `support` \[0\]): a peak is kept if at least `support`
//!    peaks lie within ±`support_rows` \[3\] BEV rows and max(`marking_width`, 2 px)
//!    laterally. Off because it drops Botts' dots (a dot spans one or two image rows); the
//!    next step judges continuity over the whole lane instead.
//! 6. **Parallel-lane filter** (`lane_support` \[3 m\]): markings are near-parallel curves in
//!    the BEV, `x = c_k + s·u + κu²/2` with one heading `s` (|s| ≤ `max_slope` \[0.3\]) and
//!    curvature κ (|κ| ≤ `max_curvature` \[0.004 /m\]) for all lanes; car edges map to radial
//!    streaks, texture and stains to short blobs. (s, κ) is the grid point that concentrates
//!    the peaks' residual histogram most (Σ h², bins 0.1 m, each peak weighted by the road
//!    length its image row covers, ≤ 1 m); lines are the histogram's maxima with at least
//!    `lane_support` metres of evidence; each line gets its own linear correction by weighted
//!    least squares (a wrong pitch or a fork bends lanes apart; each peak weighted by
//!    `(f/u)^refit_exponent` \[0.5\], f/u its row's pixels per metre: a peak's lateral error is
//!    about a pixel, so near rows fix a line's position better) and keeps the peaks within
//!    max(`lane_tol` \[0.15 m\], 1.5 px) of it, if they still add up to `lane_support` of
//!    which `bright_support` \[2 m\] from bright peaks (lines of dark seams alone are dropped).
//!    Of kept lines nearer than `line_spacing` \[0.5 m\] to each other (at 15 m ahead) only the
//!    one with the most evidence stays (the two lines of a double marking are one lane
//!    boundary). Lane boundaries are at least a lane apart: of kept lines nearer than
//!    `lane_gap` \[2.5 m\] the weaker is dropped if its evidence is below `gap_ratio` \[0.6\]
//!    of the stronger's (a slab seam, a bright strip or tyre track inside a lane, a kerb).
//!    Off by default, `gap_contrast` \[0\]: in these two tests a line's strength is its
//!    evidence with each peak weighted by min(1, R / `gap_contrast`), so a low-contrast ridge
//!    (a concrete strip, a pavement joint) counts for less than paint.
//! 7. **Output**: each kept line as samples of its fitted curve, one per image row, between its
//!    nearest and farthest peaks, across gaps between peaks of at most `fill_gap` \[12 m: one
//!    US dash period, 3 m on + 9 m off\] (0 = the peaks themselves), mapped back with
//!    [`Camera::to_image`] to (column, row). Nothing is extrapolated beyond a line's peaks.
//!
//! # Camera ([`CameraMode`])
//! The TuSimple calibration scaled to the image, a given camera, or **estimated**: the
//! vanishing point from the markings themselves ([`estimate_vanishing_point_from_lines`]: the
//! bright ridge peaks of steps 1–4 below 0.45 × the height, found with the guessed camera,
//! straight lines through them by a Hough transform, and the point nearest to most of those
//! lines; a line needs 10 peaks at 288 image rows, or 7, or 5 where no two stronger lines
//! cross, [`LINE_VOTES`]), or, if no two lines cross, from strong edges
//! ([`estimate_vanishing_point`]);
//! the camera height from the spacing of the lines through that point: the height at which their
//! lateral positions fit a comb of lane boundaries [`LANE_WIDTH`] apart best (every boundary in
//! view votes, so a seam or an oil strip inside the ego lane does not make that lane narrow;
//! the comb's tolerance, 0.5 m, was chosen on [`TUNING_SET`]: mean height error against the
//! calibration 0.040 m there, 0.192 m with the nearest lines either side of the camera as the
//! ego lane); the focal length (and a height not found) from a guess ([`Camera::guess`],
//! [`Camera::culane`] for 1640×590). The height only scales lateral metres and the focal length
//! longitudinal ones; the horizon row matters most: an error of δ rows bends parallel lanes
//! apart in the BEV (`x` off by a factor `1 + δ·u/(f·h)`). On the 10 TuSimple frames the
//! marking lines put the horizon within 3.0 rows of the calibration on every frame (the edge
//! vote alone: within 7 rows on 5 frames, 18–50 rows too high on the others), on a synthetic
//! 1640×590 road within 1 row (the edge vote: 90 rows too high). The tracker on the 10 frames:
//! 0.774 / 0.172 / 0.325 with the estimated camera ([`estimate_and_detect`]) against 0.834 /
//! 0.285 / 0.300 calibrated (before the refit weights and the lane gap: 0.761 against 0.752;
//! 0.580 with the edge vote and the guessed height; 0.701 with the
//! lines' vanishing point and the guessed height). With the height from the comb (before: the
//! ego lane's two nearest lines, which put a seam or an oil strip in as a boundary: 1.50–2.48 m
//! against the calibration's 1.67 m), 0.851 / 0.182 / 0.200 estimated against 0.848 / 0.252 /
//! 0.250 calibrated (before: 0.783 / 0.163 / 0.300 estimated); on the tuning frames 0.926
//! (before 0.885), held-out 0.775 (before 0.681). Estimating the camera costs about 3 ms (a
//! ridge pass and the Hough transform), 1.5–2 ms when detection shares the ridge pass
//! ([`estimate_and_detect`]).
//!
//! **How far off the guess may be** (`--example camera_guess_range`: the 10 frames with the
//! estimate started from the calibration moved by ±30–100 rows, ±50–100 columns, ±15–30 % focal
//! length, ±20 % height, at 1280×720): the median horizon error over the frames stays within
//! 4.1 rows (512×288) for every such guess, and the tracker's accuracy 0.63–0.82 (0.851 from
//! [`Camera::guess`]); but on one or two frames of most guesses the markings' lines miss (too
//! few bright peaks below the cut when the guess filters at the wrong scale) and the horizon is
//! 10–66 rows off. Images of one camera can share one estimate
//! ([`CameraMode::EstimateShared`], `--share clip|all`): the median of their estimates, with
//! which every image's points are found; shared by the 10 frames it is within 1.3 rows of the
//! calibration from every guess above (accuracy 0.73–0.83 for the guesses with the right focal
//! length, against 0.65–0.85 for each image's own). A guess within 0.4 × the height of the true
//! horizon row and within 100
//! columns of the vanishing column is what the estimate was built for; beyond it, give a
//! camera file. The weaker lines ([`LINE_VOTES`]: 7 and 5 peaks) were added for those misses
//! (values set a priori, not swept): guesses with a frame more than 20 rows off 14 → 7 of 17,
//! the per-image estimate under the 22 small perturbations of `--example camera_sensitivity`
//! 0.705 / 0.766 / 0.814 → 0.682 / 0.773 / 0.831 (min / median / max), `Camera::guess`
//! unchanged (every frame found its lines with 10 peaks).
//!
//! **A calibration refined** ([`CameraMode::Refine`], `--refine-horizon`): the calibration's
//! height and focal length, its vanishing point moved to the marking lines' crossing when that
//! is within [`REFINE_PITCH_DEG`] of its pitch (the road's pitch relative to the car changes
//! with braking, load and grade). On the 10 frames 0.880 / 0.188 / 0.200 against 0.838 / 0.208 /
//! 0.250 with the calibration fixed; tuning half 0.922, held-out half 0.839 (fixed 0.904 /
//! 0.771); over the 22 perturbed calibrations of `--example camera_sensitivity` 0.755 / 0.823
//! / 0.867 (fixed 0.703 / 0.791 / 0.834); about 1.4× the calibrated front end's time.
//!
//! # Measured accuracy (512×288, 10 labelled TuSimple frames)
//! The parameters were chosen on a fixed half of `data/tusimple/sample_512x288` ([`TUNING_SET`],
//! every other frame) and measured on the other half ([`HELD_OUT_SET`]), scored by [`score`]
//! (precision: points on the labelled rows within 6 px of a labelled lane; recall: per lane,
//! the labelled rows nearer than 80 m with a point within 6 px and 2 rows):
//!
//! | set | precision | mean lane recall | lanes with recall ≥ 0.25 |
//! |---|---|---|---|
//! | tuning (in-sample) | 0.799 | 0.758 | 18 of 19 |
//! | held-out | 0.637 | 0.637 | 15 of 19 |
//! | before the refit weights and the lane gap, tuning | 0.629 | 0.668 | 17 of 19 |
//! | before, held-out | 0.449 | 0.549 | 14 of 19 |
//!
//! The tracker on these points (one frame per clip, official metric at 1280×720): accuracy /
//! FP / FN 0.898 / 0.250 / 0.200 on the tuning frames, 0.771 / 0.320 / 0.400 held-out, 0.834 /
//! 0.285 / 0.300 on all 10 (before the refit weights and the lane gap: 0.848 / 0.287 / 0.250,
//! 0.655 / 0.480 / 0.550, 0.752 / 0.383 / 0.400). `refit_exponent` 0.5 (−2 / −1 / 0 / 0.5 / 1 /
//! 2 → tuning accuracy 0.723 / 0.890 / 0.846 / 0.895 / 0.833 / 0.668) and `gap_ratio` 0.6 (0 /
//! 0.5 / 0.6 / 0.7 / 0.8 / 1 → 0.895 / 0.898 / 0.898 / 0.898 / 0.834 / 0.821, precision 0.686 /
//! 0.782 / 0.799 / 0.799 / 0.803 / 0.795) were chosen the same way (0.6 and 0.7 tie exactly).
//! Chosen on the tuning frames only (the held-out ones were only
//! measured): `support` 0 and `lane_support` 3 m, `fill_gap` 12 m, `ridge_threshold` 20 (by
//! the tracker's mean accuracy there: 0.814 / 0.818 / 0.848 / 0.710 / 0.655 for 10 / 15 / 20
//! / 25 / 30), `bright_support` 2 m and `line_spacing` 0.5 m (ties on accuracy, by the sum
//! of precision and recall). Before `line_spacing`: 0.608 / 0.668 tuning, 0.389 / 0.560 held-out, tracker
//! 0.742 / 0.408 / 0.425 on all 10. Before that (the previous front end: continuity with
//! `support` 2, threshold 10, peaks as output): 0.530 / 0.484 / 16 of 19 tuning and 0.417 /
//! 0.462 / 15 of 19 held-out, tracker 0.335 on all 10. Tried and dropped: a lane-width comb
//! (lines 3.0–4.2 m apart; tuning precision 0.78 but held-out recall 0.27, it locks onto
//! barriers); a threshold relative to the road's grey level (Weber contrast 0.1–0.3; tuning
//! accuracy ≤ 0.814); correcting the horizon from the fan of the kept lines (δ = ε·f·h;
//! accuracy 0.54–0.58, no better than the vote); a minimum fraction of the strongest line's
//! evidence (tuning accuracy ≤ 0.786); `gap_contrast` (issue 16; on the tuning frames 30 and
//! 40 give exactly the default's points at `gap_ratio` 0.6, 60 / 80 / 100 / 150 / 200 a lower
//! precision, 0.782 / 0.762 / 0.762 / 0.778 / 0.778, and tracker accuracy 0.904 / 0.903 /
//! 0.903 / 0.859 / 0.859 against 0.904; at `gap_ratio` 0.7, 60 and above ≤ 0.841; so the tuning
//! half cannot choose it and it stays 0; for the record, 40 on the held-out frames: precision
//! 0.679, recall 0.636, the tracker unchanged; counting bright peaks only in the strength:
//! tuning precision 0.780, worse). A **width test** of each bright peak (stop 72, a scratch
//! build: the full width at half the peak's contrast over its brighter flank, interpolated,
//! where an image pixel is narrower than half a marking, i.e. nearer than 40 m at 512×288;
//! horizon refined, tuning half choosing): peaks wider than 0.30 m (the widest regulated
//! line) left out of the lane filter but kept for the camera fit give tuning precision /
//! recall 0.821 / 0.776 → 0.831 / 0.781 (21 points, mostly one line of 0313-2/1755), held-out
//! 0.778 / 0.703 → 0.783 / 0.701, the tracker on all ten 0.880 → 0.884; at 0.35 m the gain is
//! gone, and every tighter bound (0.15 / 0.20 / 0.25 m) loses whole lanes on the tuning half
//! (tracker 0.674 / 0.795 / 0.866): what the τ = 0.2 m filter finds on concrete strips and
//! pavement joints is about as narrow as paint. Dropping too-wide peaks before the camera fit
//! as well, counting only paint-width peaks toward `bright_support`, dropping lines whose
//! median width is too wide, and a second filter scale (0.1 / 0.16 m, the response the
//! maximum or minimum of the two) were worse on the tuning half. Not kept: a gain this small
//! and this sensitive to its bound is not worth two parameters.
//!
//! Where the false points are (issue 16, `--example frontend_diag`, default parameters, every
//! false point assigned by its line and the overlay): of the held-out half's 795 false points
//! (of 2190), 87 lie on real painted markings the label omits (edge lines, lanes two over, a
//! line past the label's end), 176 on a labelled marking but more than 6 px from its label
//! (the seam beside Botts' dots, the other line of a double line, a line fitted at a slightly
//! wrong angle), 486 on no paint (a bright concrete strip beside a slab seam: 158; an
//! asphalt–concrete pavement joint: 136; vehicles, barriers, kerbs, a shoulder's edge) and 46
//! are the filled curve past the paint; the tuning half's 427 (of 2124): 78 / 160 / 108 / 81.
//! So unlabelled paint does not bound precision: without the non-paint points the held-out
//! precision would be 1395 / 1704 = 0.819. The held-out half's 198 missed label rows: 62 on
//! Botts'-dot lines whose bright evidence is too small (one frame, ego-right and far-right
//! lines), 37 far (≥ 20 m), 35 near rows past the nearest dash (no paint there; nothing is
//! extrapolated), 27 faded or sparse dashes, 19 behind vehicles, 17 on a line found but
//! offset, 1 at the image edge (tuning half, 122: 31 / 44 / 13 / 7 / 19 / 8 far / near /
//! vehicles / Botts' dots / offset / image edge). About
//! 3 ms per image in release on a loaded 2-core machine (detection only; 4.0–4.5 ms with the
//! camera estimated by [`estimate_and_detect`]). Reproduce with `cargo run --release -p stjpdacf-tools --example
//! frontend_eval` (per-frame figures, the tracker on them, calibrated and estimated camera;
//! takes `name=value` parameter overrides) or `cargo test --release -p stjpdacf-tools --test
//! frontend -- --nocapture`.
//!
//! Images are read with the `image` crate (JPEG, PNG). [`overlay_png`] draws feature points (and
//! optionally labelled lanes) over an image for inspection.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use image::{Rgb, RgbImage};

use crate::camera::Camera;
use crate::tusimple::{Frame, TuSimpleRecord};

/// Parameters of the front end (see the module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct FrontendParams {
    /// Nearest distance of the BEV window, m.
    pub u_min: f64,
    /// Farthest distance of the BEV window, m.
    pub u_max: f64,
    /// Half-width of the BEV window, m.
    pub x_max: f64,
    /// Lateral cell size, m.
    pub dx: f64,
    /// Weight of the yellowness `max(0, (R+G)/2 − B)` added to the grey level.
    pub yellow_gain: f64,
    /// Maximum HSV saturation of white paint.
    pub white_max_sat: f64,
    /// Hue range of yellow paint, degrees.
    pub yellow_hue: (f64, f64),
    /// Minimum HSV saturation of yellow paint.
    pub yellow_min_sat: f64,
    /// Nominal marking width τ of the ridge filter, m.
    pub marking_width: f64,
    /// Minimum τ in image pixels (far rows).
    pub min_px: f64,
    /// Minimum ridge response of a feature point, grey levels.
    pub ridge_threshold: f64,
    /// Largest difference (grey levels) between a ridge's flanks and the row's median intensity
    /// (the road's grey level).
    pub road_tolerance: f64,
    /// Rows either side searched for continuity support.
    pub support_rows: usize,
    /// Peaks needed in those rows near a peak's x for it to be kept.
    pub support: usize,
    /// Adaptive part of the threshold: a peak needs `R ≥ noise_k · σ_row`, σ_row = 1.4826 ×
    /// the median |R| over the row (a robust noise level of the row's texture); 0 = off.
    pub noise_k: f64,
    /// Threshold of dark ridges (seams, e.g. concrete-slab joints along lane boundaries), in
    /// grey levels of the same filter with the polarity reversed; 0 = dark ridges are not used.
    pub dark_threshold: f64,
    /// A dark ridge within this lateral distance (m) of a bright ridge of the same row is
    /// dropped (the seam or shadow beside a painted line, not a second marking).
    pub dark_exclusion: f64,
    /// Parallel-lane filter: evidence (metres of road length along which a line has peaks, each
    /// BEV row counting its length, at most 1 m) a line needs to be kept; 0 = no filter.
    pub lane_support: f64,
    /// Parallel-lane filter: lateral tolerance (m) of a peak around its line (or 1.5 image
    /// pixels at that distance, whichever is wider).
    pub lane_tol: f64,
    /// Parallel-lane filter: largest heading of the lanes relative to the camera axis (slope
    /// dx/du) searched.
    pub max_slope: f64,
    /// Parallel-lane filter: largest curvature (1/m) searched.
    pub max_curvature: f64,
    /// Parallel-lane filter: evidence (m, as `lane_support`) a line needs from bright peaks
    /// (paint); lines of dark ridges alone (seams, oil strips, tyre tracks) are dropped.
    pub bright_support: f64,
    /// Output samples of each kept line's fitted curve, one per image row, between its nearest
    /// and farthest peaks, across gaps between peaks of at most this length (m); 0 = output the
    /// peaks themselves.
    pub fill_gap: f64,
    /// Parallel-lane filter: of kept lines nearer than this (m, at 15 m ahead) to each other,
    /// only the one with the most evidence is kept; 0 = all.
    pub line_spacing: f64,
    /// Parallel-lane filter: each peak's weight in its line's own least-squares refit is
    /// `(f/u)^refit_exponent`, f/u the pixels per metre at its distance (a peak's lateral error
    /// is about a pixel, u/f metres: 2 is inverse variance, 0 one per image row, −2 about
    /// the road length of its row, the evidence weight).
    pub refit_exponent: f64,
    /// Parallel-lane filter: the narrowest lane (m). Two lane boundaries are at least this far
    /// apart (at 15 m ahead), so of two kept lines nearer than this (but `line_spacing` or
    /// more) one is not a lane boundary (a slab seam, a bright strip, a tyre track, a kerb
    /// beside the edge line): the weaker is dropped if its evidence is below `gap_ratio` × the
    /// stronger's.
    pub lane_gap: f64,
    /// See `lane_gap`; 0 = no such test.
    pub gap_ratio: f64,
    /// Parallel-lane filter: a line's strength in the lateral suppression (`line_spacing`,
    /// `lane_gap`) is its evidence with each peak's road length weighted by min(1, R /
    /// `gap_contrast`), R its ridge response in grey levels (paint's contrast or more counts
    /// fully): of two lines too near to both be lane boundaries the one that looks more like
    /// paint stays. 0 = the evidence alone (the default: the tuning frames do not choose a
    /// value, see the module doc).
    pub gap_contrast: f64,
    /// Frame rate of the image sequences (frames per second), for the frames' time stamps: a
    /// file named `n` (`n.jpg`) is frame `n` of its clip, counted from 1 (TuSimple's clips,
    /// `1.jpg`–`20.jpg` at 20 fps) or from 0 when the clip has a file named `0`, so `t` =
    /// (`n` − 1) / `fps` or `n` / `fps`; other names: the image's index in its clip / `fps`.
    pub fps: f64,
}

impl Default for FrontendParams {
    fn default() -> Self {
        Self {
            u_min: 3.0,
            u_max: 80.0,
            x_max: 12.0,
            dx: 0.04,
            yellow_gain: 0.5,
            white_max_sat: 0.35,
            yellow_hue: (25.0, 75.0),
            yellow_min_sat: 0.2,
            marking_width: 0.2,
            min_px: 1.5,
            ridge_threshold: 20.0,
            support_rows: 3,
            support: 0,
            road_tolerance: 60.0,
            noise_k: 1.25,
            dark_threshold: 15.0,
            dark_exclusion: 1.2,
            lane_support: 3.0,
            lane_tol: 0.15,
            max_slope: 0.3,
            max_curvature: 0.004,
            fill_gap: 12.0,
            bright_support: 2.0,
            line_spacing: 0.5,
            refit_exponent: 0.5,
            lane_gap: 2.5,
            gap_ratio: 0.6,
            gap_contrast: 0.0,
            fps: 20.0,
        }
    }
}

impl FrontendParams {
    /// The names [`FrontendParams::set`] takes (`stjpdacf frontend --param NAME=VALUE`).
    pub const SETTABLE: [&'static str; 28] = [
        "u_min",
        "u_max",
        "x_max",
        "dx",
        "yellow_gain",
        "white_max_sat",
        "yellow_min_sat",
        "marking_width",
        "min_px",
        "ridge_threshold",
        "road_tolerance",
        "noise_k",
        "dark_threshold",
        "dark_exclusion",
        "lane_support",
        "lane_tol",
        "max_slope",
        "max_curvature",
        "fill_gap",
        "bright_support",
        "line_spacing",
        "refit_exponent",
        "lane_gap",
        "gap_ratio",
        "gap_contrast",
        "fps",
        "support_rows",
        "support",
    ];

    /// Set the parameter called `name` (a field name; `yellow_hue` is not settable) to `v`
    /// (rounded for the integer fields). Errors: an unknown name.
    pub fn set(&mut self, name: &str, v: f64) -> Result<()> {
        let f = match name {
            "u_min" => &mut self.u_min,
            "u_max" => &mut self.u_max,
            "x_max" => &mut self.x_max,
            "dx" => &mut self.dx,
            "yellow_gain" => &mut self.yellow_gain,
            "white_max_sat" => &mut self.white_max_sat,
            "yellow_min_sat" => &mut self.yellow_min_sat,
            "marking_width" => &mut self.marking_width,
            "min_px" => &mut self.min_px,
            "ridge_threshold" => &mut self.ridge_threshold,
            "road_tolerance" => &mut self.road_tolerance,
            "noise_k" => &mut self.noise_k,
            "dark_threshold" => &mut self.dark_threshold,
            "dark_exclusion" => &mut self.dark_exclusion,
            "lane_support" => &mut self.lane_support,
            "lane_tol" => &mut self.lane_tol,
            "max_slope" => &mut self.max_slope,
            "max_curvature" => &mut self.max_curvature,
            "fill_gap" => &mut self.fill_gap,
            "bright_support" => &mut self.bright_support,
            "line_spacing" => &mut self.line_spacing,
            "refit_exponent" => &mut self.refit_exponent,
            "lane_gap" => &mut self.lane_gap,
            "gap_ratio" => &mut self.gap_ratio,
            "gap_contrast" => &mut self.gap_contrast,
            "fps" => &mut self.fps,
            "support_rows" | "support" => {
                ensure!(
                    v.is_finite() && (0.0..=Self::MAX_SUPPORT as f64).contains(&v.round()),
                    "front-end parameter {name} = {v:?} must be a count in 0..={}",
                    Self::MAX_SUPPORT
                );
                let n = v.round() as usize;
                match name {
                    "support_rows" => self.support_rows = n,
                    _ => self.support = n,
                }
                return Ok(());
            }
            _ => bail!(
                "unknown front-end parameter {name} (one of: {})",
                Self::SETTABLE.join(", ")
            ),
        };
        *f = v;
        Ok(())
    }

    /// The largest `support_rows` and `support` (image rows and peaks).
    pub const MAX_SUPPORT: usize = 1000;
    /// The most cells of the BEV window's rows (`2 · x_max / dx`) and of the parallel-lane
    /// filter's histogram (`2 · (x_max + max_slope · u_max) / 0.1 m`): a window of 10⁹ m or
    /// cells of 10⁻⁹ m would ask for terabytes.
    pub const MAX_CELLS: f64 = 100_000.0;
    /// The largest `fps`: the tracker's clock counts microseconds, so frames closer than that
    /// would be one time (`tusimple::check_sequence`).
    pub const MAX_FPS: f64 = 1e6;

    /// Check the values (the first one out of range is the error): every parameter finite;
    /// the BEV window `0 < u_min < u_max`, `x_max` and `dx` positive, with at most
    /// [`Self::MAX_CELLS`] cells a row and in the lane filter's histogram; the lane filter's
    /// heading (≤ 10) and curvature (≤ 1 /m) searched and `refit_exponent` (|·| ≤ 10) bounded;
    /// the saturations in [0, 1]; the other thresholds, widths and distances ≥ 0;
    /// `support_rows` and `support` at most [`Self::MAX_SUPPORT`]; `0 < fps ≤ MAX_FPS`.
    ///
    /// # Errors
    /// The first parameter out of range, by name.
    pub fn validate(&self) -> Result<()> {
        let non_negative = [
            ("x_max", self.x_max),
            ("dx", self.dx),
            ("yellow_gain", self.yellow_gain),
            ("white_max_sat", self.white_max_sat),
            ("yellow_hue.0", self.yellow_hue.0),
            ("yellow_hue.1", self.yellow_hue.1),
            ("yellow_min_sat", self.yellow_min_sat),
            ("marking_width", self.marking_width),
            ("min_px", self.min_px),
            ("ridge_threshold", self.ridge_threshold),
            ("road_tolerance", self.road_tolerance),
            ("noise_k", self.noise_k),
            ("dark_threshold", self.dark_threshold),
            ("dark_exclusion", self.dark_exclusion),
            ("lane_support", self.lane_support),
            ("lane_tol", self.lane_tol),
            ("max_slope", self.max_slope),
            ("max_curvature", self.max_curvature),
            ("fill_gap", self.fill_gap),
            ("bright_support", self.bright_support),
            ("line_spacing", self.line_spacing),
            ("lane_gap", self.lane_gap),
            ("gap_ratio", self.gap_ratio),
            ("gap_contrast", self.gap_contrast),
        ];
        for (name, v) in non_negative {
            ensure!(
                v.is_finite() && v >= 0.0,
                "front-end parameter {name} = {v:?} must be finite and ≥ 0"
            );
        }
        ensure!(
            self.u_min.is_finite()
                && self.u_max.is_finite()
                && 0.0 < self.u_min
                && self.u_min < self.u_max,
            "front-end parameters u_min = {:?} and u_max = {:?} must be finite with 0 < u_min < u_max",
            self.u_min,
            self.u_max
        );
        ensure!(
            self.x_max > 0.0 && self.dx > 0.0 && 2.0 * self.x_max / self.dx <= Self::MAX_CELLS,
            "front-end parameters x_max = {:?} and dx = {:?} must be > 0 with 2·x_max/dx ≤ {} cells",
            self.x_max,
            self.dx,
            Self::MAX_CELLS
        );
        ensure!(
            self.max_slope <= 10.0 && self.max_curvature <= 1.0,
            "front-end parameters max_slope = {:?} (≤ 10) and max_curvature = {:?} (≤ 1 /m) are \
             beyond any road",
            self.max_slope,
            self.max_curvature
        );
        ensure!(
            2.0 * (self.x_max + self.max_slope * self.u_max) / 0.1 <= Self::MAX_CELLS,
            "front-end parameters x_max + max_slope·u_max = {:?} m: the lane filter's histogram \
             (0.1 m bins) would have more than {} cells",
            self.x_max + self.max_slope * self.u_max,
            Self::MAX_CELLS
        );
        ensure!(
            self.white_max_sat <= 1.0 && self.yellow_min_sat <= 1.0,
            "front-end parameters white_max_sat = {:?} and yellow_min_sat = {:?} are saturations in \
             [0, 1]",
            self.white_max_sat,
            self.yellow_min_sat
        );
        ensure!(
            self.refit_exponent.is_finite() && self.refit_exponent.abs() <= 10.0,
            "front-end parameter refit_exponent = {:?} must be in [-10, 10]",
            self.refit_exponent
        );
        ensure!(
            self.support_rows <= Self::MAX_SUPPORT && self.support <= Self::MAX_SUPPORT,
            "front-end parameters support_rows = {} and support = {} must be at most {}",
            self.support_rows,
            self.support,
            Self::MAX_SUPPORT
        );
        ensure!(
            self.fps.is_finite() && self.fps > 0.0 && self.fps <= Self::MAX_FPS,
            "fps must be a positive number of at most {:e} (the tracker's clock counts \
             microseconds), not {:?}",
            Self::MAX_FPS,
            self.fps
        );
        Ok(())
    }
}

/// A ridge peak: (BEV row index, u, x, bright, response), the response `R` (bright) or `D`
/// (dark) of the ridge filter in grey levels.
type Peak = (usize, f64, f64, bool, f64);

/// An output point of the parallel-lane filter: (u, x, line index, on a peak's row).
type LinePoint = (f64, f64, usize, bool);

/// HSV hue (degrees), saturation and value (0..255) of an RGB triple.
fn hsv([r, g, b]: [f64; 3]) -> (f64, f64, f64) {
    let max = r.max(g).max(b);
    let min = r.min(g).min(b);
    let d = max - min;
    let s = if max > 0.0 { d / max } else { 0.0 };
    let h = if d <= 0.0 {
        0.0
    } else if max == r {
        60.0 * ((g - b) / d).rem_euclid(6.0)
    } else if max == g {
        60.0 * ((b - r) / d + 2.0)
    } else {
        60.0 * ((r - g) / d + 4.0)
    };
    (h, s, max)
}

/// Feature points of one image, as image pixels `[column, row]` (bottom rows first, then by
/// column). Errors: a camera whose image size differs from the image's.
pub fn detect(img: &RgbImage, cam: &Camera, p: &FrontendParams) -> Result<Vec<[f64; 2]>> {
    check_size(img, cam)?;
    let peaks = ridge_peaks(img, cam, p, 0, i64::MAX)?;
    Ok(points_from_peaks(&peaks, cam, p))
}

/// Errors: a camera whose image size differs from the image's.
fn check_size(img: &RgbImage, cam: &Camera) -> Result<()> {
    ensure!(
        (cam.width - f64::from(img.width())).abs() < 0.5
            && (cam.height - f64::from(img.height())).abs() < 0.5,
        "camera is {}×{} but the image is {}×{} (give the camera of this image size: \
         --scale {:.4} if the images are the camera's resized, else a camera file, or \
         --camera estimate)",
        cam.width,
        cam.height,
        img.width(),
        img.height(),
        f64::from(img.width()) / cam.width
    );
    Ok(())
}

/// Steps 5–7 (continuity, parallel-lane filter, output) on the ridge peaks of [`ridge_peaks`].
fn points_from_peaks(peaks: &[Peak], cam: &Camera, p: &FrontendParams) -> Vec<[f64; 2]> {
    let mut out = Vec::new();
    // Continuity: a marking persists over neighbouring BEV rows, road texture does not. Keep a
    // peak with at least `support` peaks within ±`support_rows` rows and a lateral distance of
    // max(marking_width, 2 px).
    let by_row = |r: usize| {
        let lo = peaks.partition_point(|q| q.0 < r);
        let hi = peaks.partition_point(|q| q.0 <= r);
        &peaks[lo..hi]
    };
    let mut kept: Vec<(f64, f64, bool, f64)> = Vec::with_capacity(peaks.len());
    for &(r, u, x, bright, resp) in peaks {
        let tol = p.marking_width.max(2.0 * u / cam.focal_px);
        let n = (r.saturating_sub(p.support_rows)..=r + p.support_rows)
            .filter(|&q| q != r)
            .map(|q| by_row(q).iter().filter(|o| (o.2 - x).abs() <= tol).count())
            .sum::<usize>();
        if n >= p.support {
            kept.push((u, x, bright, resp));
        }
    }
    for (u, x, _, _) in lane_points(&kept, cam, p).0 {
        if let Some((col, row)) = cam.to_image(u, x) {
            out.push([col, row.round()]);
        }
    }
    out
}

/// Steps 6–7 on the peaks (u, x, bright) that passed the continuity test: (u, x, line, peak)
/// of every output point, `line` the index of its kept line (`usize::MAX` without the
/// parallel-lane filter) and `peak` whether a peak of that line lies on the point's image row
/// (false: a sample of the fitted curve across a gap, [`FrontendParams::fill_gap`]).
fn lane_points(
    kept: &[(f64, f64, bool, f64)],
    cam: &Camera,
    p: &FrontendParams,
) -> (Vec<LinePoint>, Vec<LineInfo>) {
    if p.lane_support > 0.0 {
        lane_filter(kept, cam, p)
    } else {
        let pts = kept.iter().map(|q| (q.0, q.1, usize::MAX, true)).collect();
        (pts, Vec::new())
    }
}

/// One output point of [`detect_tagged`], for diagnosis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TaggedPoint {
    /// Image column and row (as [`detect`]).
    pub px: [f64; 2],
    /// Index of the kept line of the parallel-lane filter it belongs to (`usize::MAX` without
    /// the filter).
    pub line: usize,
    /// Whether a ridge peak of that line lies on this image row (false: a sample of the line's
    /// fitted curve across a gap between peaks, `fill_gap`).
    pub peak: bool,
}

/// What [`detect_tagged`] returns.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Tagged {
    /// [`detect`]'s points (same order and values) with their line and kind.
    pub points: Vec<TaggedPoint>,
    /// Every ridge peak of steps 1–4 as image pixels with its polarity (`true` = bright),
    /// before the parallel-lane filter.
    pub peaks: Vec<([f64; 2], bool)>,
    /// Each kept line's statistics (indexed by [`TaggedPoint::line`]).
    pub lines: Vec<LineInfo>,
}

/// [`detect`] with the provenance of every point, for diagnosis (see [`Tagged`]).
/// Errors: as [`detect`]; continuity on (`support` > 0).
pub fn detect_tagged(img: &RgbImage, cam: &Camera, p: &FrontendParams) -> Result<Tagged> {
    check_size(img, cam)?;
    ensure!(
        p.support == 0,
        "detect_tagged: the continuity test (support > 0) is not supported"
    );
    let peaks = ridge_peaks(img, cam, p, 0, i64::MAX)?;
    let raw = peaks
        .iter()
        .filter_map(|&(_, u, x, b, _)| cam.to_image(u, x).map(|(c, r)| ([c, r.round()], b)))
        .collect();
    let kept: Vec<(f64, f64, bool, f64)> = peaks.iter().map(|q| (q.1, q.2, q.3, q.4)).collect();
    let (pts, lines) = lane_points(&kept, cam, p);
    let points = pts
        .into_iter()
        .filter_map(|(u, x, line, peak)| {
            cam.to_image(u, x).map(|(c, r)| TaggedPoint {
                px: [c, r.round()],
                line,
                peak,
            })
        })
        .collect();
    Ok(Tagged {
        points,
        peaks: raw,
        lines,
    })
}

/// Ridge peaks (steps 1–4 of the module doc) of the image rows `row_min..=row_max` inside the
/// BEV window: (BEV row index = the bottom row of the window − the image row, u, x, bright),
/// bottom row first, each row ordered by x.
fn ridge_peaks(
    img: &RgbImage,
    cam: &Camera,
    p: &FrontendParams,
    row_min: i64,
    row_max: i64,
) -> Result<Vec<Peak>> {
    let nx = (2.0 * p.x_max / p.dx).round() as usize + 1;
    let xs: Vec<f64> = (0..nx).map(|i| -p.x_max + i as f64 * p.dx).collect();
    let row_far = cam.row_at(p.u_max).context("u_max must be > 0")?.ceil() as i64;
    let row_far = row_far.max(row_min);
    let row_near = cam.row_at(p.u_min).context("u_min must be > 0")?.floor() as i64;
    let row_near = row_near.min(img.height() as i64 - 1);
    let row_hi = row_near.min(row_max);
    let mut rgb: Vec<Option<[f64; 3]>> = vec![None; nx];
    let mut inten = vec![f64::NAN; nx];
    let mut smooth = vec![f64::NAN; nx];
    let mut resp = vec![f64::NEG_INFINITY; nx];
    let mut dark = vec![f64::NEG_INFINITY; nx];
    let mut vals: Vec<f64> = Vec::with_capacity(nx);
    // (BEV row index, u, x) of every ridge peak, bottom row first.
    let mut peaks: Vec<Peak> = Vec::new();
    let w = img.width() as usize;
    for row in (row_far.max(0)..=row_hi).rev() {
        let row_idx = (row_near - row) as usize;
        let rowf = row as f64;
        let Some((u, _)) = cam.to_bev(cam.vp_col, rowf) else {
            continue;
        };
        // IPM: this BEV row, every lateral cell, sampled in the image. A BEV row is an image
        // row (`row`), so the bilinear sample is linear along it.
        let line = &img.as_raw()[row as usize * w * 3..(row as usize + 1) * w * 3];
        for (i, &x) in xs.iter().enumerate() {
            let col = cam.vp_col + cam.focal_px * x / u;
            rgb[i] = (col >= 0.0 && col <= (w - 1) as f64).then(|| {
                let c0 = col.floor() as usize;
                let fc = col - c0 as f64;
                let c1 = (c0 + 1).min(w - 1);
                std::array::from_fn(|k| {
                    f64::from(line[c0 * 3 + k]) * (1.0 - fc) + f64::from(line[c1 * 3 + k]) * fc
                })
            });
            inten[i] = match rgb[i] {
                Some([r, g, b]) => {
                    let grey = 0.299 * r + 0.587 * g + 0.114 * b;
                    grey + p.yellow_gain * ((r + g) / 2.0 - b).max(0.0)
                }
                None => f64::NAN,
            };
        }
        // Ridge filter scale for this row: the marking width or min_px pixels, in cells.
        let px_m = u / cam.focal_px;
        let tau_m = p.marking_width.max(p.min_px * px_m);
        let tau = ((tau_m / p.dx).round() as usize).max(1);
        let half = tau / 4;
        for (i, sm) in smooth.iter_mut().enumerate() {
            let lo = i.saturating_sub(half);
            let hi = (i + half).min(nx - 1);
            let v = &inten[lo..=hi];
            *sm = if v.iter().any(|x| x.is_nan()) {
                f64::NAN
            } else {
                v.iter().sum::<f64>() / v.len() as f64
            };
        }
        for i in 0..nx {
            resp[i] = f64::NEG_INFINITY;
            dark[i] = f64::NEG_INFINITY;
            if i < tau || i + tau >= nx {
                continue;
            }
            let (a, c, b) = (smooth[i - tau], smooth[i], smooth[i + tau]);
            if a.is_nan() || b.is_nan() || c.is_nan() {
                continue;
            }
            resp[i] = 2.0 * c - a - b - (a - b).abs();
            dark[i] = a + b - 2.0 * c - (a - b).abs();
        }
        // The road's grey level on this row: the median intensity over the ROI.
        vals.clear();
        vals.extend(smooth.iter().copied().filter(|v| !v.is_nan()));
        if vals.is_empty() {
            continue;
        }
        let k = vals.len() / 2;
        let road = *vals.select_nth_unstable_by(k, f64::total_cmp).1;
        // The row's texture level: a robust σ of the ridge response.
        let noise = if p.noise_k > 0.0 {
            vals.clear();
            vals.extend(resp.iter().filter(|r| r.is_finite()).map(|r| r.abs()));
            if vals.is_empty() {
                0.0
            } else {
                let k = vals.len() / 2;
                1.4826 * *vals.select_nth_unstable_by(k, f64::total_cmp).1
            }
        } else {
            0.0
        };
        let thr = p.ridge_threshold.max(p.noise_k * noise);
        let thr_dark = p.dark_threshold.max(p.noise_k * noise);
        // Threshold, road check, colour check and non-maximum suppression within ±τ.
        let row_start = peaks.len();
        for (r_arr, bright, t) in [(&resp, true, thr), (&dark, false, thr_dark)] {
            if !bright && p.dark_threshold <= 0.0 {
                continue;
            }
            for i in 0..nx {
                let r = r_arr[i];
                if r < t {
                    continue;
                }
                let lo = i.saturating_sub(tau);
                let hi = (i + tau).min(nx - 1);
                let is_max = (lo..=hi).all(|j| r_arr[j] < r || (r_arr[j] == r && j >= i));
                if !is_max {
                    continue;
                }
                // Both flanks must look like road (a marking lies on the road surface).
                let (a, b) = (smooth[i - tau], smooth[i + tau]);
                if (a - road).abs() > p.road_tolerance || (b - road).abs() > p.road_tolerance {
                    continue;
                }
                let Some(c) = rgb[i] else { continue };
                if bright {
                    let (hue, sat, _) = hsv(c);
                    let white = sat <= p.white_max_sat;
                    let yellow =
                        sat >= p.yellow_min_sat && hue >= p.yellow_hue.0 && hue <= p.yellow_hue.1;
                    if !(white || yellow) {
                        continue;
                    }
                }
                // Sub-cell refinement (parabola through the peak and its neighbours).
                let mut off = 0.0;
                if i > 0 && i + 1 < nx && r_arr[i - 1].is_finite() && r_arr[i + 1].is_finite() {
                    let (l, rr) = (r_arr[i - 1], r_arr[i + 1]);
                    let den = l - 2.0 * r + rr;
                    if den < 0.0 {
                        off = (0.5 * (l - rr) / den).clamp(-0.5, 0.5);
                    }
                }
                let x = xs[i] + off * p.dx;
                if !bright
                    && peaks[row_start..]
                        .iter()
                        .any(|q| (q.2 - x).abs() < p.dark_exclusion)
                {
                    continue;
                }
                peaks.push((row_idx, u, x, bright, r));
            }
        }
    }
    // Bright and dark peaks of a row were found in two passes: order each row by x.
    peaks.sort_by(|a, b| a.0.cmp(&b.0).then(a.2.total_cmp(&b.2)));
    Ok(peaks)
}

/// Length of road (m) one BEV row at `u` covers (one image row), at most 1 m.
fn row_length(cam: &Camera, u: f64) -> f64 {
    (u * u / (cam.focal_px * cam.height_m)).min(1.0)
}

/// Lateral tolerance (m) of a peak at `u` around a lane line.
fn lane_tolerance(cam: &Camera, p: &FrontendParams, u: f64) -> f64 {
    p.lane_tol.max(1.5 * u / cam.focal_px)
}

/// Weighted histogram of the residuals `x − s·u − κ·u²/2` of `pts` (u, x, weight) in bins of
/// `bin` m over `±span`; returns it and its concentration Σ h².
fn residual_histogram(
    pts: &[(f64, f64, f64)],
    s: f64,
    k: f64,
    bin: f64,
    span: f64,
) -> (Vec<f64>, f64) {
    let n = (2.0 * span / bin).ceil() as usize + 1;
    let mut h = vec![0.0; n];
    for &(u, x, w) in pts {
        let r = x - s * u - 0.5 * k * u * u;
        let b = ((r + span) / bin).round();
        if b >= 0.0 && (b as usize) < n {
            h[b as usize] += w;
        }
    }
    let c = h.iter().map(|v| v * v).sum();
    (h, c)
}

/// The parallel-lane filter: lane markings in the BEV are near-parallel curves
/// `x = c_k + s·u + κ·u²/2` (one heading `s` and curvature `κ` for all lanes); clutter (car
/// edges, which map to radial streaks, texture, stains) is not. Finds (s, κ) that concentrates
/// the peaks' residuals most, then the lanes (histogram maxima with at least `lane_support`
/// metres of evidence), refits each lane's own quadratic (a wrong pitch or a fork bends lanes
/// apart) and keeps the peaks within [`lane_tolerance`] of a lane.
fn lane_filter(
    peaks: &[(f64, f64, bool, f64)],
    cam: &Camera,
    p: &FrontendParams,
) -> (Vec<LinePoint>, Vec<LineInfo>) {
    let pts: Vec<(f64, f64, f64)> = peaks
        .iter()
        .map(|&(u, x, _, _)| (u, x, row_length(cam, u)))
        .collect();
    let bin = 0.1;
    let span = p.x_max + p.max_slope * p.u_max;
    // Heading on the near peaks (curvature matters little there), then curvature, then both
    // refined on a fine grid.
    let near: Vec<(f64, f64, f64)> = pts.iter().copied().filter(|q| q.0 < 25.0).collect();
    let grid =
        |lo: f64, hi: f64, n: usize| (0..=n).map(move |i| lo + (hi - lo) * i as f64 / n as f64);
    let best = |cands: &mut dyn Iterator<Item = (f64, f64)>, set: &[(f64, f64, f64)]| {
        cands
            .map(|(s, k)| (s, k, residual_histogram(set, s, k, bin, span).1))
            .fold(
                (0.0, 0.0, f64::NEG_INFINITY),
                |a, b| if b.2 > a.2 { b } else { a },
            )
    };
    let ns = (2.0 * p.max_slope / 0.01).round() as usize;
    let (s0, _, _) = best(
        &mut grid(-p.max_slope, p.max_slope, ns).map(|s| (s, 0.0)),
        &near,
    );
    let nk = (2.0 * p.max_curvature / 0.0002).round() as usize;
    let (_, k0, _) = best(
        &mut grid(-p.max_curvature, p.max_curvature, nk).map(|k| (s0, k)),
        &pts,
    );
    let (s, k, _) = best(
        &mut grid(s0 - 0.01, s0 + 0.01, 4)
            .flat_map(|s| grid(k0 - 0.0002, k0 + 0.0002, 4).map(move |k| (s, k))),
        &pts,
    );
    let (h, _) = residual_histogram(&pts, s, k, bin, span);
    // Lanes: maxima of the histogram summed over ±tolerance.
    let nb = h.len();
    let w = (p.lane_tol / bin).round().max(1.0) as usize;
    let summed: Vec<f64> = (0..nb)
        .map(|i| h[i.saturating_sub(w)..=(i + w).min(nb - 1)].iter().sum())
        .collect();
    let mut lanes: Vec<f64> = Vec::new();
    for i in 0..nb {
        let v = summed[i];
        if v < p.lane_support {
            continue;
        }
        let lo = i.saturating_sub(2 * w);
        let hi = (i + 2 * w).min(nb - 1);
        if (lo..=hi).all(|j| summed[j] < v || (summed[j] == v && j >= i)) {
            lanes.push(-span + i as f64 * bin);
        }
    }
    // Each lane's own curve: x = c + s·u + κu²/2 + a + b·u, (a, b) by weighted least squares on
    // the peaks within a band, twice with the band narrowed to the tolerance.
    // Candidate lines: (offset c, correction a, b, peak indices, evidence).
    let mut cands: Vec<(f64, f64, f64, Vec<usize>, f64)> = Vec::new();
    let mut strengths: Vec<f64> = Vec::new();
    for &c in &lanes {
        let base = |u: f64| c + s * u + 0.5 * k * u * u;
        let (mut a, mut b) = (0.0, 0.0);
        for band in [3.0, 1.5, 1.0] {
            let (mut sw, mut su, mut suu, mut sr, mut sur) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for &(u, x, _) in &pts {
                let r = x - base(u);
                if (r - a - b * u).abs() <= band * lane_tolerance(cam, p, u) {
                    let wt = (cam.focal_px / u).powf(p.refit_exponent);
                    sw += wt;
                    su += wt * u;
                    suu += wt * u * u;
                    sr += wt * r;
                    sur += wt * u * r;
                }
            }
            let det = sw * suu - su * su;
            if sw <= 0.0 || det.abs() < 1e-9 {
                break;
            }
            b = ((sw * sur - su * sr) / det).clamp(-0.05, 0.05);
            a = (sr - b * su) / sw;
        }
        let mut support = 0.0;
        let idx: Vec<usize> = (0..pts.len())
            .filter(|&i| {
                let (u, x, _) = pts[i];
                (x - base(u) - a - b * u).abs() <= lane_tolerance(cam, p, u)
            })
            .collect();
        let mut bright = 0.0;
        for &i in &idx {
            support += pts[i].2;
            if peaks[i].2 {
                bright += pts[i].2;
            }
        }
        if support >= p.lane_support && bright >= p.bright_support {
            // Its strength for the lateral suppression: the evidence with each peak's road
            // length weighted by its ridge response relative to paint's, min(1, R / `gap_contrast`)
            // (a low-contrast ridge, a concrete strip or a pavement joint, counts for less).
            let strength = if p.gap_contrast > 0.0 {
                idx.iter()
                    .map(|&i| pts[i].2 * (peaks[i].3 / p.gap_contrast).clamp(0.0, 1.0))
                    .sum()
            } else {
                support
            };
            cands.push((c, a, b, idx, support));
            strengths.push(strength);
        }
    }
    // Lateral non-maximum suppression: of lines nearer than `line_spacing` to each other (at
    // 15 m) only the one with the most evidence is a marking (double lines, seams and the
    // shadow beside a line are not separate lanes).
    let at = |l: &(f64, f64, f64, Vec<usize>, f64), u: f64| {
        l.0 + s * u + 0.5 * k * u * u + l.1 + l.2 * u
    };
    let mut order: Vec<usize> = (0..cands.len()).collect();
    order.sort_by(|&i, &j| strengths[j].total_cmp(&strengths[i]));
    let mut chosen: Vec<usize> = Vec::new();
    for i in order {
        if chosen.iter().all(|&j| {
            let d = (at(&cands[i], 15.0) - at(&cands[j], 15.0)).abs();
            d >= p.line_spacing && (d >= p.lane_gap || strengths[i] >= p.gap_ratio * strengths[j])
        }) {
            chosen.push(i);
        }
    }
    chosen.sort_unstable();
    let mut keep = vec![usize::MAX; pts.len()];
    let mut filled: Vec<LinePoint> = Vec::new();
    for (li, &ci) in chosen.iter().enumerate() {
        let (c, a, b, ref idx, _) = cands[ci];
        let base = |u: f64| c + s * u + 0.5 * k * u * u;
        {
            if p.fill_gap > 0.0 {
                let mut us: Vec<f64> = idx.iter().map(|&i| pts[i].0).collect();
                us.sort_by(f64::total_cmp);
                for w in us.windows(2) {
                    if w[1] - w[0] > p.fill_gap {
                        continue;
                    }
                    let (r0, r1) = (cam.row_at(w[1]), cam.row_at(w[0]));
                    let (Some(r0), Some(r1)) = (r0, r1) else {
                        continue;
                    };
                    let mut r = r0.ceil();
                    while r <= r1.floor() {
                        if let Some((u, _)) = cam.to_bev(cam.vp_col, r) {
                            if !filled.iter().any(|q: &LinePoint| {
                                q.0 == u && (q.1 - base(u) - a - b * u).abs() < 0.3
                            }) {
                                let peak = idx.iter().any(|&i| pts[i].0 == u);
                                filled.push((u, base(u) + a + b * u, li, peak));
                            }
                        }
                        r += 1.0;
                    }
                }
            }
            for &i in idx {
                if keep[i] == usize::MAX {
                    keep[i] = li;
                }
            }
        }
    }
    let infos = chosen
        .iter()
        .map(|&ci| {
            let idx = &cands[ci].3;
            let mut resp: Vec<f64> = idx
                .iter()
                .filter(|&&i| peaks[i].2)
                .map(|&i| peaks[i].3)
                .collect();
            let median = if resp.is_empty() {
                0.0
            } else {
                let m = resp.len() / 2;
                *resp.select_nth_unstable_by(m, f64::total_cmp).1
            };
            let (lo, hi) = idx.iter().fold((f64::INFINITY, 0.0f64), |a, &i| {
                (a.0.min(pts[i].0), a.1.max(pts[i].0))
            });
            LineInfo {
                offset: cands[ci].0 + cands[ci].1 + 15.0 * cands[ci].2,
                correction: (cands[ci].1, cands[ci].2),
                evidence: cands[ci].4,
                bright_evidence: idx.iter().filter(|&&i| peaks[i].2).map(|&i| pts[i].2).sum(),
                median_response: median,
                u_range: (lo, hi),
            }
        })
        .collect();
    if p.fill_gap > 0.0 {
        filled.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.total_cmp(&b.1)));
        return (filled, infos);
    }
    let out = peaks
        .iter()
        .zip(keep)
        .filter_map(|(&q, k)| (k != usize::MAX).then_some((q.0, q.1, k, true)))
        .collect();
    (out, infos)
}

/// Statistics of one kept line of the parallel-lane filter (for diagnosis, [`detect_tagged`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineInfo {
    /// Lateral position (m) 15 m ahead, relative to the common curve's heading
    /// (`c + a + 15·b`).
    pub offset: f64,
    /// The line's own linear correction (a m, b) to the common curve.
    pub correction: (f64, f64),
    /// Evidence (m of road length with a peak on the line, as `lane_support`).
    pub evidence: f64,
    /// Evidence from bright peaks.
    pub bright_evidence: f64,
    /// Median ridge response `R` of its bright peaks, grey levels (0 if none).
    pub median_response: f64,
    /// Nearest and farthest distance (m) of its peaks.
    pub u_range: (f64, f64),
}

/// Image files (`*.jpg`, `*.jpeg`, `*.png`, any case) under `dir`, recursively, in the order
/// frames are written: by folder, then by frame number ([`frame_number`]: TuSimple's `1.jpg …
/// 20.jpg`), then by name.
pub fn find_images(dir: &Path) -> Result<Vec<PathBuf>> {
    find_files(dir, |path| {
        path.extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "jpg" | "jpeg" | "png"))
    })
}

/// The files under `dir`, recursively, that `keep` accepts, in [`find_images`]' order.
pub fn find_files(dir: &Path, keep: impl Fn(&Path) -> bool) -> Result<Vec<PathBuf>> {
    fn walk(d: &Path, keep: &dyn Fn(&Path) -> bool, out: &mut Vec<PathBuf>) -> Result<()> {
        for e in std::fs::read_dir(d).with_context(|| format!("reading folder {}", d.display()))? {
            let path = e
                .with_context(|| format!("reading folder {}", d.display()))?
                .path();
            if path.is_dir() {
                walk(&path, keep, out)?;
            } else if keep(&path) {
                out.push(path);
            }
        }
        Ok(())
    }
    let mut out = Vec::new();
    walk(dir, &keep, &mut out)?;
    let key = |p: &PathBuf| {
        (
            p.parent().map(Path::to_path_buf),
            frame_number(p),
            p.file_name().map(|n| n.to_os_string()),
        )
    };
    out.sort_by_key(key);
    Ok(out)
}

/// The frame number of a file named by one up to its first dot (`20.jpg`, `00030.png`,
/// `00030.lines.txt`).
pub fn frame_number(path: &Path) -> Option<u64> {
    let name = path.file_name()?.to_str()?;
    name.split('.').next()?.parse().ok()
}

/// `path` relative to `dir`, with `/` separators (a TuSimple `raw_file`).
pub fn raw_file_of(dir: &Path, path: &Path) -> String {
    let rel = path.strip_prefix(dir).unwrap_or(path);
    rel.components()
        .map(|c| c.as_os_str().to_string_lossy())
        .collect::<Vec<_>>()
        .join("/")
}

/// Read an image as RGB8.
pub fn load_rgb(path: &Path) -> Result<RgbImage> {
    Ok(image::open(path)
        .with_context(|| format!("reading image {}", path.display()))?
        .to_rgb8())
}

/// The camera for an image: `camera` if given (its size must match), else the TuSimple camera
/// scaled to the image's width (the image must have TuSimple's 16:9 shape).
pub fn camera_for(img: &RgbImage, camera: Option<&Camera>) -> Result<Camera> {
    if let Some(c) = camera {
        return Ok(*c);
    }
    let s = f64::from(img.width()) / 1280.0;
    let cam = Camera::tusimple().scaled(s);
    ensure!(
        (cam.height - f64::from(img.height())).abs() < 1.0,
        "a {}×{} image is not a scaled 1280×720 TuSimple frame; give --camera FILE",
        img.width(),
        img.height()
    );
    Ok(cam)
}

/// How the front end gets each image's camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CameraMode {
    /// The TuSimple camera scaled to each image ([`camera_for`] with no camera).
    TuSimple,
    /// This camera for every image (its size must match).
    Given(Camera),
    /// This calibrated camera (scaled to each image's width, as the guess of `Estimate`) with
    /// its vanishing point moved to where the image's marking lines cross
    /// ([`refine_and_detect`]) when that lies within [`REFINE_PITCH_DEG`] of the camera's pitch;
    /// its height and focal length stay. For a fixed camera on a road whose pitch relative to
    /// the camera changes (grades, braking, load) and a calibration fitted on other frames.
    Refine(Camera),
    /// The horizon and the vanishing column estimated from each image
    /// ([`estimate_vanishing_point_from_lines`], else [`estimate_vanishing_point`]), the camera
    /// height from the spacing of the marking lines (lane boundaries [`LANE_WIDTH`] apart); the
    /// focal length, and whatever is not found, from this guess (scaled to the image's width).
    Estimate(Camera),
    /// One camera for a group of images ([`Share`]): the estimate of [`CameraMode::Estimate`]
    /// (`fit` [`Fit::Camera`]) or the refinement of [`CameraMode::Refine`] ([`Fit::Horizon`])
    /// from `guess` on the group's first image and every `every`-th after it (`every` 0 is
    /// taken as 1), the median of those estimates ([`Camera::median`]), and every image's
    /// points found with it ([`run_dir_cameras`]). An image whose own estimate missed moves
    /// neither its points nor its clip's BEV, and the estimate costs time only on the images it
    /// runs on. A group of one image (and [`camera_with`]'s single image) is estimated as under
    /// `Estimate` (or `Refine`).
    EstimateShared {
        /// The camera the estimates start from (the calibration, for [`Fit::Horizon`]).
        guess: Camera,
        /// Which images share a camera.
        share: Share,
        /// Estimate on every `every`-th image of a group.
        every: usize,
        /// What the images' markings may change of `guess`.
        fit: Fit,
    },
}

/// Which images share one camera under [`CameraMode::EstimateShared`]; images of different
/// sizes never do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Share {
    /// The images of one clip (one folder): one drive of one camera. What `stjpdacf track`
    /// assumes when it maps a clip with the median of its frames' cameras.
    Clip,
    /// Every image (of one size) under the folder: images from one camera, e.g. single frames
    /// of many drives of one car.
    All,
}

/// The vanishing point of the road's markings in `img`, `(column, row)`: every strong
/// grey-level edge (the strongest 10 %) below 0.55 × the height that is neither
/// near-horizontal nor near-vertical votes, weighted by its gradient magnitude × its distance
/// to the candidate row, for the points of its line on the candidate horizon rows
/// (`0.15–0.5 × height`); the most-voted point (votes smoothed over ±2 px) wins. Lane markings, kerbs and barriers all run towards the vanishing point; car
/// edges (vertical or horizontal) do not vote or spread their votes. `None` if fewer than 200
/// edge pixels vote (no road markings to go by).
pub fn estimate_vanishing_point(img: &RgbImage) -> Option<(f64, f64)> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    if w < 16 || h < 16 {
        return None;
    }
    let grey: Vec<f32> = img
        .pixels()
        .map(|p| 0.299 * f32::from(p[0]) + 0.587 * f32::from(p[1]) + 0.114 * f32::from(p[2]))
        .collect();
    let g = |c: usize, r: usize| grey[r * w + c];
    let (r0, r1) = (h * 11 / 20, h - 2);
    // Sobel gradients of the lower half; the threshold is the 90th percentile of the magnitude.
    let mut edges: Vec<(f32, f32, f32, f32)> = Vec::new();
    for r in r0..=r1 {
        for c in 1..w - 1 {
            let gx = g(c + 1, r - 1) + 2.0 * g(c + 1, r) + g(c + 1, r + 1)
                - g(c - 1, r - 1)
                - 2.0 * g(c - 1, r)
                - g(c - 1, r + 1);
            let gy = g(c - 1, r + 1) + 2.0 * g(c, r + 1) + g(c + 1, r + 1)
                - g(c - 1, r - 1)
                - 2.0 * g(c, r - 1)
                - g(c + 1, r - 1);
            let m = (gx * gx + gy * gy).sqrt();
            if m > 40.0 {
                edges.push((c as f32, r as f32, gx, gy));
            }
        }
    }
    let mut mags: Vec<f32> = edges.iter().map(|e| e.2.hypot(e.3)).collect();
    if mags.len() < 200 {
        return None;
    }
    let k = mags.len() * 9 / 10;
    let thr = *mags.select_nth_unstable_by(k, f32::total_cmp).1;
    let (y_lo, y_hi) = ((0.15 * h as f64) as usize, (0.5 * h as f64) as usize);
    let ny = y_hi - y_lo + 1;
    let mut acc = vec![0.0f32; ny * w];
    let mut voters = 0usize;
    for &(c, r, gx, gy) in &edges {
        let m = gx.hypot(gy);
        if m < thr {
            continue;
        }
        // Line direction (dc, dr) ⟂ gradient; skip near-horizontal and near-vertical lines.
        let (dc, dr) = (-gy / m, gx / m);
        if dr.abs() < 0.3 || dc.abs() < 0.1 {
            continue;
        }
        voters += 1;
        let slope = dc / dr;
        for (yi, y) in (y_lo..=y_hi).enumerate() {
            let x = c + (y as f32 - r) * slope;
            if x >= 0.0 && x < w as f32 {
                // A line's crossing spreads with the distance from its pixel (its angle is
                // uncertain): weighting by that distance makes near and far rows comparable.
                acc[yi * w + x as usize] += m * (r - y as f32) / h as f32;
            }
        }
    }
    if voters < 200 {
        return None;
    }
    // Smooth ±2 px and take the maximum.
    let mut best = (0usize, 0usize, f32::NEG_INFINITY);
    for yi in 2..ny.saturating_sub(2) {
        for x in 2..w - 2 {
            let mut v = 0.0;
            for dy in 0..5 {
                v += acc[(yi + dy - 2) * w + x - 2..=(yi + dy - 2) * w + x + 2]
                    .iter()
                    .sum::<f32>();
            }
            if v > best.2 {
                best = (x, yi, v);
            }
        }
    }
    Some((best.0 as f64, (y_lo + best.1) as f64))
}

/// Straight lines through the bright ridge peaks of the lower image (`(point, unit normal,
/// inlier count)`, the line being `n·q = n·point`), strongest first: a Hough transform (1°,
/// 1 px) of the peaks, each line refitted by total least squares on the peaks within `tol` px
/// and its votes removed before the next.
fn marking_lines(
    pts: &[(f64, f64)],
    tol: f64,
    min_votes: usize,
) -> Vec<([f64; 2], [f64; 2], usize)> {
    const NT: usize = 180;
    // Line directions within 80° of vertical: θ is the normal's angle, normals within 80° of
    // horizontal.
    let thetas: Vec<(f64, f64)> = (0..NT)
        .map(|i| (i as f64 - 90.0).to_radians())
        .map(|t| (t.cos(), t.sin()))
        .collect();
    // Coordinates relative to the peaks' centroid keep the ρ range small.
    let m = pts.len().max(1) as f64;
    let o = pts
        .iter()
        .fold((0.0, 0.0), |a, q| (a.0 + q.0 / m, a.1 + q.1 / m));
    let pts: Vec<(f64, f64)> = pts.iter().map(|q| (q.0 - o.0, q.1 - o.1)).collect();
    let pts = &pts[..];
    let rmax = pts
        .iter()
        .map(|q| q.0.hypot(q.1))
        .fold(0.0f64, f64::max)
        .ceil()
        + 1.0;
    let nr = (2.0 * rmax) as usize + 1;
    let mut acc = vec![0i32; NT * nr];
    let bin = |q: (f64, f64), t: usize| {
        let (c, s) = thetas[t];
        ((q.0 * c + q.1 * s + rmax).round() as usize).min(nr - 1)
    };
    let usable = |t: usize| (t as i64 - 90).abs() <= 80;
    let vote = |acc: &mut [i32], q: (f64, f64), d: i32| {
        for t in (0..NT).filter(|&t| usable(t)) {
            acc[t * nr + bin(q, t)] += d;
        }
    };
    for &q in pts {
        vote(&mut acc, q, 1);
    }
    let mut alive = vec![true; pts.len()];
    let mut lines = Vec::new();
    for _ in 0..12 {
        // The strongest cell, its votes summed with the ρ neighbours (a line's peaks straddle
        // bins).
        let mut best = (0usize, 0usize, 0i32);
        for t in (0..NT).filter(|&t| usable(t)) {
            let row = &acc[t * nr..(t + 1) * nr];
            for r in 1..nr - 1 {
                let v = row[r - 1] + row[r] + row[r + 1];
                if v > best.2 {
                    best = (t, r, v);
                }
            }
        }
        if (best.2 as usize) < min_votes {
            break;
        }
        let (c, s) = thetas[best.0];
        let mut n = [c, s];
        let mut rho = best.1 as f64 - rmax;
        let mut inl: Vec<usize> = Vec::new();
        for it in 0..3 {
            let band = if it == 0 { 1.5 } else { tol };
            inl = (0..pts.len())
                .filter(|&i| alive[i] && (n[0] * pts[i].0 + n[1] * pts[i].1 - rho).abs() <= band)
                .collect();
            if inl.len() < 3 {
                break;
            }
            let m = inl.len() as f64;
            let (mx, my) = inl
                .iter()
                .fold((0.0, 0.0), |a, &i| (a.0 + pts[i].0 / m, a.1 + pts[i].1 / m));
            let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
            for &i in &inl {
                let (dx, dy) = (pts[i].0 - mx, pts[i].1 - my);
                sxx += dx * dx;
                sxy += dx * dy;
                syy += dy * dy;
            }
            // Normal = eigenvector of the smaller eigenvalue of the scatter matrix.
            let ang = 0.5 * (2.0 * sxy).atan2(sxx - syy) + std::f64::consts::FRAC_PI_2;
            n = [ang.cos(), ang.sin()];
            rho = n[0] * mx + n[1] * my;
        }
        // Remove the peaks of this line (inliers of the refit, or the Hough cell's).
        let mut removed = 0;
        for i in 0..pts.len() {
            let near_fit = (n[0] * pts[i].0 + n[1] * pts[i].1 - rho).abs() <= tol;
            let near_cell = bin(pts[i], best.0).abs_diff(best.1) <= 1;
            if alive[i] && (near_fit || near_cell) {
                alive[i] = false;
                vote(&mut acc, pts[i], -1);
                removed += 1;
            }
        }
        if removed == 0 {
            break;
        }
        // Lines within 80° of vertical only (n not near-vertical).
        if inl.len() >= min_votes && n[1].abs() < 0.985 {
            let (mx, my) = inl.iter().fold((0.0, 0.0), |a, &i| {
                (
                    a.0 + pts[i].0 / inl.len() as f64,
                    a.1 + pts[i].1 / inl.len() as f64,
                )
            });
            lines.push(([mx + o.0, my + o.1], n, inl.len()));
        }
    }
    lines
}

/// The vanishing point `(column, row)` of the lane markings, from the markings themselves: the
/// bright ridge peaks (steps 1–4, with `guess` as camera) below 0.45 × the height, straight
/// lines through them (a Hough transform, each line of at least 10 peaks at 288 rows refitted
/// by total least squares), then the point nearest (perpendicular distance) to the most lines,
/// weighted by their peaks: every pair of lines crossing between 0.05 and 0.6 × the height
/// proposes its crossing, the proposal with the most weight within `0.015 × height` px wins
/// and is refined by least squares on those lines. `None` without two such lines.
pub fn estimate_vanishing_point_from_lines(
    img: &RgbImage,
    guess: &Camera,
    p: &FrontendParams,
) -> Option<(f64, f64)> {
    vanishing_point_and_lines(img, guess, p).map(|(q, _)| q)
}

/// A marking line through the vanishing point: (slope dcol/drow = x / camera height, its
/// peaks).
type VpLine = (f64, f64);

/// [`estimate_vanishing_point_from_lines`], also returning the lines through the point.
fn vanishing_point_and_lines(
    img: &RgbImage,
    guess: &Camera,
    p: &FrontendParams,
) -> Option<((f64, f64), Vec<VpLine>)> {
    let peaks = ridge_peaks(img, guess, p, lines_row_min(img), i64::MAX).ok()?;
    vanishing_point_of_peaks(img, guess, &peaks)
}

/// The first image row whose ridge peaks make the lines of
/// [`estimate_vanishing_point_from_lines`]: 0.45 × the height.
fn lines_row_min(img: &RgbImage) -> i64 {
    (0.45 * f64::from(img.height())).ceil() as i64
}

/// Peaks a marking line of the per-image camera estimate needs (at 288 image rows; scaled with
/// the height), strongest first: the weaker entries are tried only when no two lines of the
/// previous one cross (see the module doc, "How far off the guess may be").
pub const LINE_VOTES: [f64; 3] = [10.0, 7.0, 5.0];

/// [`vanishing_point_and_lines`] from ridge peaks found with `guess`.
fn vanishing_point_of_peaks(
    img: &RgbImage,
    guess: &Camera,
    peaks: &[Peak],
) -> Option<((f64, f64), Vec<VpLine>)> {
    let h = f64::from(img.height());
    let pts: Vec<(f64, f64)> = peaks
        .iter()
        .filter(|q| q.3)
        .filter_map(|q| guess.to_image(q.1, q.2))
        .filter(|q| q.0 >= 0.0 && q.0 < f64::from(img.width()))
        .collect();
    let s = h / 288.0;
    let tol = 0.015 * h;
    let dist = |l: &([f64; 2], [f64; 2], usize), q: [f64; 2]| {
        (l.1[0] * (q[0] - l.0[0]) + l.1[1] * (q[1] - l.0[1])).abs()
    };
    // The crossing of two lines that the most peaks' lines pass through.
    let best_crossing = |lines: &[([f64; 2], [f64; 2], usize)]| {
        let mut best: Option<([f64; 2], f64)> = None;
        for i in 0..lines.len() {
            for j in i + 1..lines.len() {
                let (a, b) = (&lines[i], &lines[j]);
                let det = a.1[0] * b.1[1] - a.1[1] * b.1[0];
                if det.abs() < 0.05 {
                    continue;
                }
                let (ra, rb) = (
                    a.1[0] * a.0[0] + a.1[1] * a.0[1],
                    b.1[0] * b.0[0] + b.1[1] * b.0[1],
                );
                let q = [
                    (ra * b.1[1] - rb * a.1[1]) / det,
                    (a.1[0] * rb - b.1[0] * ra) / det,
                ];
                if !(q[1] >= 0.05 * h && q[1] <= 0.6 * h) {
                    continue;
                }
                let w: f64 = lines
                    .iter()
                    .filter(|l| dist(l, q) <= tol)
                    .map(|l| l.2 as f64)
                    .sum();
                if best.is_none_or(|b| w > b.1) {
                    best = Some((q, w));
                }
            }
        }
        best
    };
    // Lines of at least `LINE_VOTES` peaks; where no two of them cross (few markings below
    // the cut, or all on one side), the weaker lines too, down to the last entry.
    let (lines, (mut q, _)) = LINE_VOTES.iter().find_map(|&v| {
        let lines = marking_lines(&pts, 1.5 * s.max(1.0), (v * s).round() as usize);
        best_crossing(&lines).map(|b| (lines, b))
    })?;
    // Least squares on the lines through the proposal: minimise Σ w (n·q − ρ)².
    for _ in 0..2 {
        let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for l in lines.iter().filter(|l| dist(l, q) <= tol) {
            let w = l.2 as f64;
            let rho = l.1[0] * l.0[0] + l.1[1] * l.0[1];
            a11 += w * l.1[0] * l.1[0];
            a12 += w * l.1[0] * l.1[1];
            a22 += w * l.1[1] * l.1[1];
            b1 += w * l.1[0] * rho;
            b2 += w * l.1[1] * rho;
        }
        let det = a11 * a22 - a12 * a12;
        if det.abs() < 1e-9 {
            break;
        }
        q = [(a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det];
    }
    // Each line through the vanishing point as its slope dcol/drow = x / camera height, and
    // its peaks.
    let slopes = lines
        .iter()
        .filter(|l| dist(l, q) <= tol)
        .map(|l| (-l.1[1] / l.1[0], l.2 as f64))
        .collect();
    Some(((q[0], q[1]), slopes))
}

/// Lateral tolerance σ (m) of the lane-boundary comb of [`height_from_lane_lattice`], chosen on
/// [`TUNING_SET`] with the camera estimated: σ = 0.15 / 0.3 / 0.4 / 0.5 / 0.6 / 0.8 m → mean
/// height error against the calibration's 1.67 m 0.070 / 0.066 / 0.038 / 0.040 / 0.042 / 0.040 m,
/// tracker accuracy 0.903 / 0.897 / 0.918 / 0.926 / 0.926 / 0.907 (0.5 and 0.6 tie on accuracy;
/// 0.5 has the smaller height error). Lane widths and the lines' lateral positions extrapolated
/// to the camera both vary by a few decimetres.
const LATTICE_SIGMA: f64 = 0.5;

/// The camera height (m), in 1.0–2.5 m, at which the lines through the vanishing point (as
/// (slope dcol/drow = x/height, weight)) lie best on lane boundaries `lane_width` apart: each
/// line's lateral position `x = slope·h` is scored against a comb `x₀ + k·lane_width` (any offset
/// x₀) by its weight × exp(−d²/2σ²), d its distance to the nearest tooth, σ =
/// [`LATTICE_SIGMA`]. All the lane boundaries in view vote, so a seam, an oil strip or a kerb
/// (a line that is not on the comb) barely moves the estimate, where taking the nearest line
/// either side of the camera as the ego lane would make that lane too narrow. `None` if the best
/// comb has fewer than two teeth with a line within 2σ (one line, or lines all together).
fn height_from_lane_lattice(lines: &[(f64, f64)], lane_width: f64) -> Option<f64> {
    if lines.len() < 2 {
        return None;
    }
    let sig = LATTICE_SIGMA;
    let score = |h: f64, x0: f64| -> f64 {
        lines
            .iter()
            .map(|&(sl, w)| {
                let r = (sl * h - x0).rem_euclid(lane_width);
                let d = r.min(lane_width - r);
                w * (-0.5 * (d / sig).powi(2)).exp()
            })
            .sum()
    };
    // The best (h, x₀, score) over a grid.
    let search = |hs: &[f64], x0s: &[f64]| {
        let mut best = (f64::NAN, 0.0, f64::NEG_INFINITY);
        for &h in hs {
            for &x0 in x0s {
                let v = score(h, x0);
                if v > best.2 {
                    best = (h, x0, v);
                }
            }
        }
        best
    };
    // A coarse grid (h every 0.02 m, x₀ every 0.1 m), then a fine one around its best.
    let hs: Vec<f64> = (0..=75).map(|i| 1.0 + 0.02 * f64::from(i)).collect();
    let x0s: Vec<f64> = (0..(lane_width / 0.1).ceil() as i32)
        .map(|i| 0.1 * f64::from(i))
        .collect();
    let (h0, x00, _) = search(&hs, &x0s);
    let hs: Vec<f64> = (-8..=8)
        .map(|i| h0 + 0.0025 * f64::from(i))
        .filter(|h| (1.0..=2.5).contains(h))
        .collect();
    let x0s: Vec<f64> = (-5..=5).map(|i| x00 + 0.02 * f64::from(i)).collect();
    let best = search(&hs, &x0s);
    let (h, x0, _) = best;
    let mut teeth: Vec<i64> = lines
        .iter()
        .filter_map(|&(sl, _)| {
            let k = ((sl * h - x0) / lane_width).round();
            ((sl * h - x0 - k * lane_width).abs() <= 2.0 * sig).then_some(k as i64)
        })
        .collect();
    teeth.sort_unstable();
    teeth.dedup();
    (teeth.len() >= 2).then_some(h)
}

/// Width of a lane (m) assumed when the camera height is estimated from an image: a US
/// interstate lane is 12 ft (3.66 m); [`Camera::tusimple`]'s height was fitted to 3.7 m.
pub const LANE_WIDTH: f64 = 3.7;

/// The camera of `img` under `mode` (see [`CameraMode`]).
pub fn camera_with(img: &RgbImage, mode: &CameraMode) -> Result<Camera> {
    match mode {
        CameraMode::TuSimple => camera_for(img, None),
        CameraMode::Given(c) => camera_for(img, Some(c)),
        CameraMode::Estimate(guess) => {
            fit_camera(img, guess, &FrontendParams::default(), Fit::Camera)
        }
        CameraMode::EstimateShared { guess, fit, .. } => {
            fit_camera(img, guess, &FrontendParams::default(), *fit)
        }
        CameraMode::Refine(c) => fit_camera(img, c, &FrontendParams::default(), Fit::Horizon),
    }
}

/// The camera of `img` estimated from its markings ([`CameraMode::Estimate`]), starting from
/// `guess` (scaled to the image's width); [`estimate_and_detect`] also finds the points.
pub fn estimate_camera(img: &RgbImage, guess: &Camera, p: &FrontendParams) -> Result<Camera> {
    fit_camera(img, guess, p, Fit::Camera)
}

/// How far from a calibrated camera's pitch [`CameraMode::Refine`] moves its horizon: 1°, the
/// order of a car's pitch under braking or load and of a change of road grade (at the 512×288
/// TuSimple scale, 7 rows). Set from those magnitudes, not fitted to the bundled frames (on
/// them 3 / 5 / 8 / 100 rows gave 0.873 / 0.880 / 0.880 / 0.824 accuracy: one frame's lines
/// cross 10 rows above the calibration's horizon; docs/measurements.md).
pub const REFINE_PITCH_DEG: f64 = 1.0;

/// What an image's markings may change of the camera the front end starts from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fit {
    /// [`CameraMode::Estimate`]: the vanishing point (the marking lines', else the edge vote)
    /// and the camera height (the lines' spacing).
    Camera,
    /// [`CameraMode::Refine`]: the marking lines' vanishing point only, within
    /// [`REFINE_PITCH_DEG`] of the camera's pitch.
    Horizon,
}

/// [`estimate_camera`], or its refinement of a calibrated camera (`Fit::Horizon`).
fn fit_camera(img: &RgbImage, start: &Camera, p: &FrontendParams, fit: Fit) -> Result<Camera> {
    let g = scaled_guess(img, start);
    let peaks = ridge_peaks(img, &g, p, lines_row_min(img), i64::MAX)?;
    Ok(camera_from_peaks(img, &g, &peaks, fit))
}

/// `guess` scaled to `img`'s width, with `img`'s height.
fn scaled_guess(img: &RgbImage, guess: &Camera) -> Camera {
    let mut cam = guess.scaled(f64::from(img.width()) / guess.width);
    cam.height = f64::from(img.height());
    cam
}

/// The estimated camera ([`CameraMode::Estimate`]) or the refined one
/// ([`CameraMode::Refine`], `fit`) from the ridge peaks found with the scaled guess `g` on the
/// rows below [`lines_row_min`].
fn camera_from_peaks(img: &RgbImage, g: &Camera, peaks: &[Peak], fit: Fit) -> Camera {
    let mut cam = *g;
    // The markings' own lines first; the edge vote if fewer than two lines cross.
    let found = vanishing_point_of_peaks(img, g, peaks);
    if fit == Fit::Horizon {
        // A row shift of f·tan δ is a pitch change of δ.
        let window = g.focal_px * REFINE_PITCH_DEG.to_radians().tan();
        if let Some(((c, r), _)) = found.filter(|f| (f.0 .1 - g.vp_row).abs() <= window) {
            cam.vp_col = c;
            cam.vp_row = r;
        }
        return cam;
    }
    let vp = found
        .as_ref()
        .map(|f| f.0)
        .or_else(|| estimate_vanishing_point(img));
    if let Some((c, r)) = vp {
        cam.vp_col = c;
        cam.vp_row = r;
    }
    // The camera height from the lane boundaries' spacing, else the guess's.
    if let Some(h) = found
        .as_ref()
        .and_then(|f| height_from_lane_lattice(&f.1, LANE_WIDTH))
    {
        cam.height_m = h;
    }
    cam
}

/// Largest relative difference of the guessed and the estimated camera's scale (pixels per
/// metre across an image row) at which [`estimate_and_detect`] reuses the guess's ridge peaks
/// of that row (chosen on the tuning frames: 0.05 / 0.1 / 0.15 / 0.25 → tracker accuracy
/// 0.811 / 0.819 / 0.818 / 0.793 there).
const REUSE_SCALE: f64 = 0.1;

/// The camera estimated from `img` ([`CameraMode::Estimate`] of `guess`) and the feature points
/// of `img` with it ([`detect`]), sharing most of one ridge pass: the peaks found with the
/// guess on the rows that make the marking lines are mapped to the estimated camera's BEV (a
/// BEV row is an image row; only the ridge filter's width in pixels differs, by the ratio of
/// the two cameras' scales) where that ratio is within `REUSE_SCALE` (0.1) of 1, and the other
/// rows are filtered again with the estimated camera.
pub fn estimate_and_detect(
    img: &RgbImage,
    guess: &Camera,
    p: &FrontendParams,
) -> Result<(Camera, Vec<[f64; 2]>)> {
    fit_and_detect(img, guess, p, Fit::Camera)
}

/// The calibrated `camera` refined from `img` ([`CameraMode::Refine`]) and the feature points
/// of `img` with it, sharing the ridge pass as [`estimate_and_detect`] does.
pub fn refine_and_detect(
    img: &RgbImage,
    camera: &Camera,
    p: &FrontendParams,
) -> Result<(Camera, Vec<[f64; 2]>)> {
    fit_and_detect(img, camera, p, Fit::Horizon)
}

/// [`estimate_and_detect`] or [`refine_and_detect`] (`fit`).
fn fit_and_detect(
    img: &RgbImage,
    start: &Camera,
    p: &FrontendParams,
    fit: Fit,
) -> Result<(Camera, Vec<[f64; 2]>)> {
    let g = scaled_guess(img, start);
    let r0 = lines_row_min(img);
    let near = ridge_peaks(img, &g, p, r0, i64::MAX)?;
    let cam = camera_from_peaks(img, &g, &near, fit);
    let row_near = cam.row_at(p.u_min).context("u_min must be > 0")?.floor() as i64;
    let row_near = row_near.min(img.height() as i64 - 1);
    // Rows where the two cameras' scales (pixels per metre across the row) differ by more
    // than `REUSE_SCALE` are filtered again with the estimated camera.
    let scale = |c: &Camera, r: f64| (r - c.vp_row) / c.height_m;
    let mut r_new = r0;
    while r_new <= row_near
        && (scale(&g, r_new as f64) / scale(&cam, r_new as f64) - 1.0).abs() > REUSE_SCALE
    {
        r_new += 1;
    }
    let mut peaks = ridge_peaks(img, &cam, p, 0, r_new - 1)?;
    for &(_, u, x, bright, resp) in &near {
        let Some((col, row)) = g.to_image(u, x) else {
            continue;
        };
        let row = row.round();
        if (row as i64) < r_new {
            continue;
        }
        let Some((u2, x2)) = cam.to_bev(col, row) else {
            continue;
        };
        if u2 >= p.u_min && u2 <= p.u_max && x2.abs() <= p.x_max && (row as i64) <= row_near {
            peaks.push(((row_near - row as i64) as usize, u2, x2, bright, resp));
        }
    }
    peaks.sort_by(|a, b| a.0.cmp(&b.0).then(a.2.total_cmp(&b.2)));
    Ok((cam, points_from_peaks(&peaks, &cam, p)))
}

/// Run the front end on every image under `dir` (see [`find_images`]): one [`Frame`] per image,
/// `raw_file` = its path relative to `dir`, `clip` = that path's folder, `t` from the file's
/// frame number and [`FrontendParams::fps`] (TuSimple's `n.jpg`: (n − 1) × 0.05 s), or the
/// image's index in its folder / `fps`,
/// `h_samples` from `labels` when one has the same `raw_file`, `camera` the camera its points were
/// found with. `camera`: `None` = the TuSimple camera scaled to each image. `progress` is called
/// after each image.
pub fn run_dir(
    dir: &Path,
    camera: Option<&Camera>,
    labels: &[TuSimpleRecord],
    p: &FrontendParams,
    progress: impl FnMut(usize, usize),
) -> Result<Vec<Frame>> {
    Ok(run_dir_timed(dir, camera, labels, p, progress)?
        .into_iter()
        .map(|(f, _)| f)
        .collect())
}

/// [`run_dir`], also returning the time [`detect`] took on each image (ms: IPM to feature
/// points; reading and decoding the file are not counted).
pub fn run_dir_timed(
    dir: &Path,
    camera: Option<&Camera>,
    labels: &[TuSimpleRecord],
    p: &FrontendParams,
    progress: impl FnMut(usize, usize),
) -> Result<Vec<(Frame, f64)>> {
    let mode = camera.map_or(CameraMode::TuSimple, |c| CameraMode::Given(*c));
    Ok(run_dir_cameras(dir, &mode, labels, p, progress)?
        .into_iter()
        .map(|(f, ms, _)| (f, ms))
        .collect())
}

/// What to tell a user whose labels name none of the images: `None` when `labels` is empty or
/// at least one frame got its `h_samples` from them. A label belongs to an image when its
/// `raw_file` is the image's path under the images' folder ([`raw_file_of`]); TuSimple labels
/// name one image of each clip, so most frames of a clip have none and only a file that
/// matches no image at all is reported (every frame then lacks the rows `track` writes a
/// prediction at, and `eval` has nothing to score).
pub fn unmatched_labels_note(frames: &[Frame], labels: &[TuSimpleRecord]) -> Option<String> {
    let (first_label, first_image) = (labels.first()?, frames.first()?);
    if frames.iter().any(|f| f.h_samples.is_some()) {
        return None;
    }
    Some(format!(
        "none of the {} labels names one of the {} images: a label's raw_file must be the \
         image's path under the images' folder (the first image is {:?}, the first label names \
         {:?}); no frame has h_samples, so `track` writes no prediction for them and `eval` \
         has nothing to score",
        labels.len(),
        frames.len(),
        first_image.raw_file.as_deref().unwrap_or_default(),
        first_label.raw_file
    ))
}

/// [`run_dir_timed`] with the camera of each image from `mode`, also returning that camera
/// (the time includes estimating it, on the images an estimate ran on). Under
/// [`CameraMode::EstimateShared`] the groups' estimates run first (their images are read twice).
pub fn run_dir_cameras(
    dir: &Path,
    mode: &CameraMode,
    labels: &[TuSimpleRecord],
    p: &FrontendParams,
    mut progress: impl FnMut(usize, usize),
) -> Result<Vec<(Frame, f64, Camera)>> {
    let files = find_images(dir)?;
    if files.is_empty() {
        bail!("no *.jpg or *.png images under {}", dir.display());
    }
    let clip_of = |raw_file: &str| {
        raw_file
            .rsplit_once('/')
            .map(|(d, _)| d.to_string())
            .unwrap_or_default()
    };
    p.validate()?;
    // Clips whose files are numbered from 0.
    let zero_based: std::collections::HashSet<String> = files
        .iter()
        .filter(|f| frame_number(f) == Some(0))
        .map(|f| clip_of(&raw_file_of(dir, f)))
        .collect();
    // Shared estimates first: each group's camera, and the time the estimate took per image.
    let mut shared: Vec<Option<Camera>> = vec![None; files.len()];
    let mut estimate_ms = vec![0.0; files.len()];
    if let CameraMode::EstimateShared {
        guess,
        share,
        every,
        fit,
    } = mode
    {
        let mut groups: HashMap<(String, (u32, u32)), Vec<usize>> = HashMap::new();
        let mut order = Vec::new();
        for (n, path) in files.iter().enumerate() {
            let key = match share {
                Share::Clip => clip_of(&raw_file_of(dir, path)),
                Share::All => String::new(),
            };
            let dims = image::image_dimensions(path)
                .with_context(|| format!("reading image {}", path.display()))?;
            let members = groups.entry((key.clone(), dims)).or_default();
            if members.is_empty() {
                order.push((key, dims));
            }
            members.push(n);
        }
        for key in &order {
            let members = groups.get(key).map_or(&[][..], Vec::as_slice);
            if members.len() < 2 {
                continue; // one image: its own estimate, as `Estimate`
            }
            let mut cams = Vec::new();
            for &n in members.iter().step_by((*every).max(1)) {
                let img = load_rgb(&files[n])?;
                let start = std::time::Instant::now();
                cams.push(
                    fit_camera(&img, guess, p, *fit)
                        .with_context(|| format!("{}", files[n].display()))?,
                );
                estimate_ms[n] = start.elapsed().as_secs_f64() * 1e3;
            }
            let cam = Camera::median(&cams);
            for &n in members {
                shared[n] = cam;
            }
        }
    }
    let dt = 1.0 / p.fps;
    let mut frames: Vec<Frame> = Vec::with_capacity(files.len());
    let mut times = Vec::with_capacity(files.len());
    let mut cams = Vec::with_capacity(files.len());
    let mut index_in_clip = 0usize;
    // The image size of the previous image, to hold a clip (one drive of one camera) to one.
    let mut prev_dims = (0, 0);
    for (n, path) in files.iter().enumerate() {
        let img = load_rgb(path)?;
        let raw_file = raw_file_of(dir, path);
        let clip = clip_of(&raw_file);
        // `track` maps a clip with one camera; a folder of two image sizes is two cameras (or a
        // resized copy beside the original) and its points would be mapped with the wrong one.
        if let Some(prev) = frames.last().filter(|prev| prev.clip == clip) {
            ensure!(
                img.dimensions() == prev_dims,
                "{}: {}x{} pixels, but {} in the same folder (clip) is {}x{}: a clip's images \
                 come from one camera at one size; put each size in its own folder",
                path.display(),
                img.width(),
                img.height(),
                prev.raw_file.as_deref().unwrap_or_default(),
                prev_dims.0,
                prev_dims.1
            );
        }
        prev_dims = img.dimensions();
        let start = std::time::Instant::now();
        let (cam, points) = match (mode, shared[n]) {
            (CameraMode::EstimateShared { .. }, Some(cam)) => {
                detect(&img, &cam, p).map(|points| (cam, points))
            }
            (CameraMode::Estimate(guess), _) => estimate_and_detect(&img, guess, p),
            (CameraMode::EstimateShared { guess, fit, .. }, None) => {
                fit_and_detect(&img, guess, p, *fit)
            }
            (CameraMode::Refine(cal), _) => refine_and_detect(&img, cal, p),
            _ => camera_with(&img, mode).and_then(|cam| Ok((cam, detect(&img, &cam, p)?))),
        }
        .with_context(|| format!("{}", path.display()))?;
        cams.push(cam);
        times.push(start.elapsed().as_secs_f64() * 1e3 + estimate_ms[n]);
        // The image's index in its clip (files of one folder are consecutive).
        index_in_clip = match frames.last() {
            Some(prev) if prev.clip == clip => index_in_clip + 1,
            _ => 0,
        };
        let t = match frame_number(path) {
            Some(k) if zero_based.contains(clip.as_str()) => k as f64 * dt,
            Some(k) if k >= 1 => (k - 1) as f64 * dt,
            _ => index_in_clip as f64 * dt,
        };
        // A folder that mixes numbered and other names (or numbers twice, `1.jpg` and
        // `01.png`) would give two images one time: `track` refuses such a clip.
        if let Some(prev) = frames.last().filter(|prev| prev.clip == clip) {
            ensure!(
                t > prev.t,
                "{}: time {t} s is not after {}'s {} s: a file named by a number n is frame n \
                 of its clip, other names are numbered in order, so a folder must not mix them \
                 (nor repeat a number); rename or move the files",
                path.display(),
                prev.raw_file.as_deref().unwrap_or_default(),
                prev.t
            );
        }
        let h_samples = labels
            .iter()
            .find(|l| l.raw_file == raw_file)
            .map(|l| l.h_samples.clone());
        let frame = Frame {
            clip,
            t,
            points,
            raw_file: Some(raw_file),
            h_samples,
            // Always the camera the points were found with (calibrated ones too): `track` maps
            // the frames with it, so a 512×288 file needs no --scale and cannot get the wrong one.
            camera: Some(cam),
        };
        // What `track` checks (`Frame::check`): a time its microsecond clock holds (a file
        // named by a nanosecond time stamp is frame 10¹⁸ or so, beyond it).
        frame.check().with_context(|| {
            format!(
                "{}: a file named by a number n is frame n of its clip, at time (n − 1) / \
                 --fps; rename the files (frame numbers) or give another --fps",
                path.display()
            )
        })?;
        frames.push(frame);
        progress(n + 1, files.len());
    }
    Ok(frames
        .into_iter()
        .zip(times)
        .zip(cams)
        .map(|((f, t), c)| (f, t, c))
        .collect())
}

/// Draw `points` (red dots, 3×3 px) and, if given, labelled `lanes` (green dots at the label
/// rows) over `img`.
pub fn overlay(img: &RgbImage, points: &[[f64; 2]], lanes: Option<&TuSimpleRecord>) -> RgbImage {
    let mut out = img.clone();
    let mut dot = |c: f64, r: f64, colour: Rgb<u8>, rad: i64| {
        let (c, r) = (c.round() as i64, r.round() as i64);
        for dr in -rad..=rad {
            for dc in -rad..=rad {
                let (x, y) = (c + dc, r + dr);
                if x >= 0 && y >= 0 && (x as u32) < out.width() && (y as u32) < out.height() {
                    out.put_pixel(x as u32, y as u32, colour);
                }
            }
        }
    };
    if let Some(l) = lanes {
        for lane in &l.lanes {
            for (&x, &y) in lane.iter().zip(&l.h_samples) {
                if x >= 0.0 {
                    dot(x, y, Rgb([0, 255, 0]), 2);
                }
            }
        }
    }
    for p in points {
        dot(p[0], p[1], Rgb([255, 0, 0]), 1);
    }
    out
}

/// Write [`overlay`] of the image at `image` to the PNG file `out`.
pub fn overlay_png(
    image: &Path,
    points: &[[f64; 2]],
    lanes: Option<&TuSimpleRecord>,
    out: &Path,
) -> Result<()> {
    let img = load_rgb(image)?;
    overlay(&img, points, lanes)
        .save_with_format(out, image::ImageFormat::Png)
        .with_context(|| format!("writing {}", out.display()))
}

/// The fixed split of the 10 bundled 512×288 TuSimple frames (`data/tusimple/sample_512x288`):
/// the parameters are tuned on these five (every other frame in [`find_images`] order)…
pub const TUNING_SET: [&str; 5] = [
    "clips/0313-1/14900/20.jpg",
    "clips/0313-1/33600/20.jpg",
    "clips/0313-2/1755/20.jpg",
    "clips/0313-2/30360/20.jpg",
    "clips/0313-2/37400/20.jpg",
];

/// …and measured, untouched by tuning, on these five.
pub const HELD_OUT_SET: [&str; 5] = [
    "clips/0313-1/25440/20.jpg",
    "clips/0313-1/8260/20.jpg",
    "clips/0313-2/24720/20.jpg",
    "clips/0313-2/3300/20.jpg",
    "clips/0313-2/520/20.jpg",
];

/// Column of a labelled lane at image row `y` (linear between label rows), all scaled by `s`.
fn lane_x(l: &TuSimpleRecord, lane: &[f64], y: f64, s: f64) -> Option<f64> {
    let pts: Vec<(f64, f64)> = l
        .h_samples
        .iter()
        .zip(lane)
        .filter(|(_, &x)| x >= 0.0)
        .map(|(&h, &x)| (h * s, x * s))
        .collect();
    pts.windows(2).find_map(|w| {
        let ((ya, xa), (yb, xb)) = (w[0], w[1]);
        (ya <= y && y <= yb).then(|| {
            if yb > ya {
                xa + (xb - xa) * (y - ya) / (yb - ya)
            } else {
                xa
            }
        })
    })
}

/// Feature-point scores summed over frames ([`score`] per frame): precision over all points,
/// each lane's recall.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointTally {
    /// Points within tolerance of a labelled lane.
    pub tp: usize,
    /// Points on the labelled rows.
    pub n: usize,
    /// Each labelled lane's recall.
    pub recalls: Vec<f64>,
}

impl PointTally {
    /// Adds frame `raw`'s score; returns its line for a per-frame listing.
    pub fn add(&mut self, raw: &str, (tp, n, recalls): (usize, usize, Vec<f64>)) -> String {
        let line = format!(
            "  {raw}: {n} points, precision {:.3}, lane recall {recalls:.2?}",
            tp as f64 / n as f64
        );
        self.tp += tp;
        self.n += n;
        self.recalls.extend(recalls);
        line
    }

    /// Precision over all points.
    pub fn precision(&self) -> f64 {
        self.tp as f64 / self.n as f64
    }

    /// Mean lane recall.
    pub fn mean_recall(&self) -> f64 {
        self.recalls.iter().sum::<f64>() / self.recalls.len() as f64
    }

    /// Lanes with recall ≥ 0.25.
    pub fn covered(&self) -> usize {
        self.recalls.iter().filter(|&&r| r >= 0.25).count()
    }
}

/// Score of one frame's feature points against its label: `(true, all)` points on the labelled
/// rows (true = within `tol` px of a labelled lane, interpolated between label rows), and each
/// lane's recall (the fraction of its label rows nearer than 80 m with a point within `tol` px
/// and 2 rows). The frame's pixels are the label's × `s`.
pub fn score(
    points: &[[f64; 2]],
    l: &TuSimpleRecord,
    s: f64,
    tol: f64,
) -> (usize, usize, Vec<f64>) {
    let (ymin, ymax) = (l.h_samples[0] * s, l.h_samples[l.h_samples.len() - 1] * s);
    let (mut tp, mut n) = (0, 0);
    for p in points.iter().filter(|p| p[1] >= ymin && p[1] <= ymax) {
        n += 1;
        let hit = l
            .lanes
            .iter()
            .filter_map(|lane| lane_x(l, lane, p[1], s))
            .any(|x| (x - p[0]).abs() < tol);
        tp += usize::from(hit);
    }
    let cam = Camera::tusimple().scaled(0.4 * s);
    let row_far = cam.row_at(80.0).unwrap_or(0.0);
    let mut rec = Vec::new();
    for lane in &l.lanes {
        let rows: Vec<(f64, f64)> = l
            .h_samples
            .iter()
            .zip(lane)
            .filter(|(&h, &x)| x >= 0.0 && h * s >= row_far)
            .map(|(&h, &x)| (h * s, x * s))
            .collect();
        if rows.is_empty() {
            continue;
        }
        let hit = rows
            .iter()
            .filter(|(y, x)| {
                points
                    .iter()
                    .any(|p| (p[0] - x).abs() < tol && (p[1] - y).abs() <= 2.0 * s)
            })
            .count();
        rec.push(hit as f64 / rows.len() as f64);
    }
    (tp, n, rec)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every name the unknown-parameter message lists is one `set` takes, and each sets a
    /// different field.
    #[test]
    fn settable_names_are_the_ones_set_takes() {
        let base = FrontendParams::default();
        for name in FrontendParams::SETTABLE {
            let mut p = base.clone();
            p.set(name, 7.0).unwrap();
            assert_ne!(format!("{p:?}"), format!("{base:?}"), "{name}");
        }
        let e = base.clone().set("nope", 1.0).unwrap_err();
        assert!(format!("{e}").contains("(one of: u_min, u_max,"), "{e}");
    }

    /// Lines through the vanishing point at lateral offsets `xs` (m) seen from height `h`, as
    /// (slope x/h, weight).
    fn lines_at(xs: &[f64], h: f64) -> Vec<(f64, f64)> {
        xs.iter().map(|&x| (x / h, 20.0)).collect()
    }

    #[test]
    fn height_from_the_lane_comb() {
        // Four boundaries 3.7 m apart, the camera 0.3 m right of the ego lane's centre.
        let h = 1.67;
        let lanes = [-5.85, -2.15, 1.55, 5.25];
        let est = height_from_lane_lattice(&lines_at(&lanes, h), LANE_WIDTH).unwrap();
        assert!((est - h).abs() < 0.02, "{est}");
        // A seam 0.6 m inside the ego lane and a kerb 1 m beyond the last line: the nearest
        // lines either side of the camera would make the ego lane 2.75 m wide; the comb
        // is not moved far.
        let mut xs = lanes.to_vec();
        xs.extend([0.95, 6.25]);
        let est = height_from_lane_lattice(&lines_at(&xs, h), LANE_WIDTH).unwrap();
        assert!((est - h).abs() < 0.1, "{est}");
        // Two lines (the ego lane) fix the height; one line, or two lines of one double
        // marking, do not.
        let est = height_from_lane_lattice(&lines_at(&[-1.85, 1.85], 2.0), LANE_WIDTH).unwrap();
        assert!((est - 2.0).abs() < 0.02, "{est}");
        assert_eq!(
            height_from_lane_lattice(&lines_at(&[1.85], h), LANE_WIDTH),
            None
        );
        assert_eq!(
            height_from_lane_lattice(&lines_at(&[1.8, 1.95], h), LANE_WIDTH),
            None
        );
    }
}
