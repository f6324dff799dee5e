//! `stjpdacf`: the command-line tool of the ST-JPDACF lane tracker.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

use stjpdacf_reference::hyper::HyperFile;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::demo;
use stjpdacf_tools::frontend;
use stjpdacf_tools::metric;
use stjpdacf_tools::rownoise;
use stjpdacf_tools::synth::{self, NoiseLevel, SynthParams};
use stjpdacf_tools::tablegen;
use stjpdacf_tools::track::MAX_REPORT_MISSES;
use stjpdacf_tools::trainrun;
use stjpdacf_tools::tusimple;

#[derive(Parser)]
#[command(name = "stjpdacf", version, about = "ST-JPDACF lane tracker: tools")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// Coordinates of the frames' points.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum SpaceArg {
    /// Image pixels `[column, row]`.
    Image,
    /// BEV metres `[x, u]`.
    Bev,
}

/// Which model `track` runs (`track::Model`).
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ModelArg {
    /// The reference model (C `stjpdacf_init`; Rust `ReferenceTracker`).
    Reference,
    /// The same tables at Gram rank 5 (C `stjpdacf_rank5_init`; Rust `Rank5Tracker`).
    Rank5,
    /// The smallest model: uncoupled tables, Gram rank 4, LBP on every row (C
    /// `stjpdacf_small_init`; Rust `Rank4Tracker` on `UNCOUPLED`).
    Small,
    /// The cheapest model the firmware measures: uncoupled tables, Gram rank 3, LBP on every
    /// row (Rust `Rank3Tracker` on `UNCOUPLED`; `bench/firmware/budget-rank3.json`).
    Rank3,
}

/// Which images share one camera estimate (`frontend --camera estimate --share`).
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ShareArg {
    /// Each image its own estimate.
    Image,
    /// One camera per clip (folder): the median of its images' estimates.
    Clip,
    /// One camera for every image of one size: the median of all estimates.
    All,
}

/// `eval --metric`.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum MetricArg {
    Tusimple,
    Culane,
}

#[derive(Subcommand)]
enum Command {
    /// Generate the static model tables (a Rust source file) from a hyperparameter file.
    Tables {
        /// Hyperparameter file (JSON, schema stjpdacf-hyper/v1) [default: the checkout's
        /// data/hyper/default.json, from any working folder].
        #[arg(long)]
        hyper: Option<PathBuf>,
        /// Output Rust file (`-` for standard output).
        #[arg(long, default_value = "-")]
        out: PathBuf,
        /// Name of the generated `static`.
        #[arg(long, default_value = "DEFAULT")]
        name: String,
    },
    /// Print how well the RBF state-space approximation of each Taylor order matches the true
    /// kernel (a Markdown table, as in the README).
    Kernels,
    /// Run the tracker over frames of feature points and write TuSimple predictions.
    Track {
        /// Frames (JSON lines: clip, t, points, raw_file?, h_samples?).
        #[arg(long)]
        frames: PathBuf,
        /// Output predictions (TuSimple JSON lines).
        #[arg(long)]
        out: PathBuf,
        /// Hyperparameter file (default: the built-in tables of data/hyper/default.json).
        #[arg(long)]
        hyper: Option<PathBuf>,
        /// The model to run, as the firmware and the C API offer it: the same lanes, bit for
        /// bit, as the tracker compiled for it (`small` and `rank3` use the built-in uncoupled
        /// tables, so not with --hyper).
        #[arg(long, value_enum, default_value_t = ModelArg::Reference)]
        model: ModelArg,
        /// Camera: `tusimple` (1280x720), `culane` (a 1640x590 guess) or a camera JSON file
        /// (fields width, height, vp_col, vp_row, height_m, focal_px). A clip whose frames carry
        /// their own cameras (`stjpdacf frontend --camera estimate`) is mapped with the median
        /// of those instead.
        #[arg(long, default_value = "tusimple")]
        camera: String,
        /// Image scale relative to the camera (0.4 for 512x288 frames with `--camera tusimple`).
        #[arg(long)]
        scale: Option<f64>,
        /// Coordinates of the points: image pixels `[column, row]` of the camera, or BEV metres
        /// `[x lateral, u ahead]` (then the camera only maps the lanes back to the h_samples rows).
        #[arg(long, value_enum, default_value_t = SpaceArg::Image)]
        space: SpaceArg,
        /// Also write the BEV points the tracker gets, with the rows of each prediction: the
        /// input of the C example `capi/examples/track.c` (format: `track::write_points_header`).
        #[arg(long)]
        export_points: Option<PathBuf>,
        /// Score each lane's existence with its rows discounted 1/K per index interval
        /// (`PersistConfig::paint_gap = None`, docs/design.md §11.5) instead of the default paint /
        /// gap chain along its rows: fewer lane ids on structured clutter, fewer sparse dashed
        /// lanes found in dense clutter.
        #[arg(long)]
        interval_evidence: bool,
        /// Act only on decisive rays (`PersistConfig::ray_aligned = false`, docs/design.md
        /// §11.10): a lane consistent with a ray whose offset at the camera's foot point is not
        /// resolved is kept even when it runs parallel to no marking (an ablation).
        #[arg(long)]
        decisive_rays_only: bool,
        /// Turn a new lane away when every slot is taken (`PersistConfig::slot_claims = false`,
        /// docs/design.md §11.13) instead of giving it the slot of a lane whose existence fell
        /// below the birth prior (an ablation).
        #[arg(long)]
        no_slot_claims: bool,
        /// The narrowest lane, metres (`PersistConfig::lane_width`, docs/design.md §11.14): a
        /// lane closer than this to a lane on either side, or beside the outermost marking, is
        /// tracked but not published. 0 publishes every line structure (kerbs, road edges).
        #[arg(long, default_value_t = stjpdacf::persist::PersistConfig::DEFAULT.lane_width)]
        lane_width: f32,
        /// Weigh every known lane's detections in the joint events at the spatial stage's
        /// `P_D` instead of the lane's learned `P_D,b` (`PersistConfig::own_pd = false`,
        /// docs/design.md §11.3; the behaviour until stop 55, an ablation).
        #[arg(long)]
        no_own_pd: bool,
        /// Publish a new lane from its second frame even when it runs parallel to no lane found
        /// to be paint or lies within 2 m of a published lane (`PersistConfig::newcomer_wait =
        /// 0`, docs/design.md §11.5; an ablation).
        #[arg(long)]
        no_newcomer_wait: bool,
        /// The most frames a new lane that is not yet shown to be a marking of its own waits
        /// before it is published (`PersistConfig::newcomer_wait`, default 2; 0 = no wait).
        #[arg(long, value_name = "FRAMES", conflicts_with = "no_newcomer_wait")]
        newcomer_wait: Option<u8>,
        /// Write the per-frame baseline's predictions instead of the tracker's: the sequential
        /// RANSAC fit of BEV quadratics to each frame's preprocessed points on its own, no
        /// tracking (`stjpdacf_tools::baseline`, the baseline of the demo's robustness and
        /// held-out rows), to compare the two on your own data with `eval`. `--baseline 4` caps
        /// it at 4 lanes (the better of the two on the held-out check).
        #[arg(long, value_name = "MAX_LANES", num_args = 0..=1, default_missing_value = "0")]
        baseline: Option<usize>,
        /// The within-frame row-noise scale of the known-lane stage
        /// (`PersistConfig::row_noise_scale`, docs/design.md §11.12; default 0.043, fitted to the
        /// bundled labels under the default tables): for a hyperparameter file of your own
        /// (--hyper), `stjpdacf row-noise --hyper` fits it.
        #[arg(long, value_name = "SCALE")]
        row_noise_scale: Option<f32>,
        /// Also draw each frame's tracked lanes on its image into this folder (one PNG per frame
        /// whose `raw_file` names an image under --images: the image in grey, the points red,
        /// each lane in its id's colour, solid where observed, dotted where extrapolated, with
        /// its ±2σ band; labelled lanes green with --labels).
        #[arg(long, requires = "images")]
        overlay: Option<PathBuf>,
        /// The folder the frames' `raw_file`s are relative to (for --overlay); the camera
        /// (--camera, --scale) must be the images' own.
        #[arg(long, requires = "overlay")]
        images: Option<PathBuf>,
        /// TuSimple labels drawn green on the overlays where their `raw_file` is a frame's.
        #[arg(long, requires = "overlay")]
        labels: Option<PathBuf>,
        /// Write a prediction for every frame, not only for those with `h_samples` (labelled
        /// frames): a frame without rows gets TuSimple's (160–710 px every 10 px of 720, scaled
        /// to the camera's height), one without `raw_file` the name `clip/k` (k from 0). For
        /// your own unlabelled sequences; `eval` wants one prediction per labelled frame, so
        /// leave it off to score.
        #[arg(long)]
        every_frame: bool,
        /// Also write the tracker's lanes of every frame with their ids (JSON lines, one per
        /// frame: clip, t, raw_file, rejected, index_u, and per lane id, existence, age, hits,
        /// misses, u_first, u_last, and x and var at the index points, BEV metres; and the
        /// fixed-lag smoother's lanes of the frame 4 frames back, `smoothed_t`, `smoothed`):
        /// `stjpdacf_tools::track::LanesFrame`.
        #[arg(long)]
        lanes: Option<PathBuf>,
    },
    /// Score TuSimple predictions against ground truth with the official TuSimple metric.
    Eval {
        /// Predictions (TuSimple JSON lines with `raw_file`, `lanes`, `run_time`).
        #[arg(long)]
        pred: PathBuf,
        /// Ground truth (TuSimple JSON lines with `raw_file`, `lanes`, `h_samples`).
        #[arg(long)]
        gt: PathBuf,
        /// Print `{"Accuracy": .., "FP": .., "FN": .., "frames": ..}` instead of a table.
        #[arg(long)]
        json: bool,
        /// Multiply every column and row of both files by this before scoring (2.5 scores files
        /// of 512x288 frames at TuSimple's 1280x720, where the metric's 20 px threshold is set).
        #[arg(long, default_value_t = 1.0)]
        pixel_scale: f64,
        /// Also write every frame's score (JSON lines `{"raw_file", "accuracy", "fp", "fn",
        /// "gt_lanes", "pred_lanes", "penalty"}`, worst accuracy first) to this file, and
        /// list the worst frames on stderr.
        #[arg(long, value_name = "OUT.jsonl")]
        per_frame: Option<PathBuf>,
        /// Also write every labelled lane's rows as the metric sees them (JSON lines
        /// `{"raw_file", "label", "pred", "accuracy", "matched", "pred_taken", "right",
        /// "both_absent", "off", "missing", "extra"}`: its best prediction and that
        /// prediction's rows within the threshold, beyond it, labelled but not predicted,
        /// predicted but not labelled), and sum up on stderr how the unmatched lanes were lost.
        #[arg(long, value_name = "OUT.jsonl")]
        per_lane: Option<PathBuf>,
        /// Score only the predictions of frames the ground truth lists and say how many others
        /// were left out (the official scorer refuses a prediction of an unlabelled frame). For
        /// predictions of every frame of a clip against labels of its last frame, as `synth
        /// --gt` writes them; a labelled frame without a prediction is still an error.
        #[arg(long)]
        labelled_only: bool,
        /// The metric: `tusimple` (the official TuSimple scorer) or `culane` (CULane's: lanes
        /// drawn --lane-px wide on an --image-size image, matched one to one when their pixels'
        /// intersection over union exceeds --iou; TP, FP, FN, precision, recall, F1).
        #[arg(long, value_enum, default_value = "tusimple")]
        metric: MetricArg,
        /// With `--metric culane`: the lanes' stroke width, pixels (CULane's 30).
        #[arg(long, default_value_t = 30.0, value_name = "PX")]
        lane_px: f64,
        /// With `--metric culane`: the IoU a match must exceed (CULane's 0.5; 0.3 is also used).
        #[arg(long, default_value_t = 0.5)]
        iou: f64,
        /// With `--metric culane`: the image size the lanes are drawn on, `WxH` (after
        /// --pixel-scale).
        #[arg(long, default_value = "1640x590")]
        image_size: String,
    },
    /// Convert CULane-style lane files (`*.lines.txt` beside each image: a lane a line, `x y`
    /// pairs in pixels; CULane, CurveLanes, many detectors' outputs) to TuSimple ground truth
    /// for `eval`, `train` and `synth` and to frames of points for `track`, or TuSimple records
    /// (`track`'s predictions) back to lane files for CULane's own evaluator.
    #[command(group(clap::ArgGroup::new("input").required(true)))]
    Convert {
        /// A folder of lane files, searched recursively: write its TuSimple records to --out
        /// (`raw_file` = the image's path relative to this folder; every --row-step rows over
        /// the rows each image's lanes cover, or the rows of --labels; linear interpolation
        /// between a lane's points; points outside --camera's image left out and counted; an
        /// empty file is an image without lanes).
        #[arg(long, value_name = "DIR", group = "input")]
        culane: Option<PathBuf>,
        /// TuSimple records (JSON lines: predictions or labels): write each as a lane file
        /// `<--out>/<raw_file without extension>.lines.txt`.
        #[arg(long, value_name = "FILE", group = "input")]
        to_culane: Option<PathBuf>,
        /// With --culane: the TuSimple records (JSON lines). With --to-culane: the folder.
        #[arg(long)]
        out: PathBuf,
        /// With --culane: also write the lanes as frames of feature points for `track` (every
        /// image row between a lane's points; clip = the image's folder; t = the file's frame
        /// number / --fps, files without one 1 / --fps apart in name order), to track labels
        /// as a perfect detector's output or a per-frame detector's lane files over time.
        #[arg(long, value_name = "FILE", requires = "culane")]
        frames: Option<PathBuf>,
        /// With --culane: TuSimple labels (`convert --culane` of the label files, with its
        /// folder at the same level as this one so that `raw_file`s match). The records are
        /// then sampled at the labels' rows and written as predictions (`run_time` 0: not
        /// timed), so `eval --pred OUT --gt LABELS` scores the lane files as they are, and the
        /// frames carry those rows, so `track` predicts each labelled image where `eval` scores
        /// it (frames of images the labels do not name get no prediction).
        #[arg(long, value_name = "FILE", requires = "culane")]
        labels: Option<PathBuf>,
        /// Rows between the records' h_samples, pixels (multiples of it; CULane labels a point
        /// every 10 rows).
        #[arg(long, default_value_t = 10.0, requires = "culane")]
        row_step: f64,
        /// Frame rate the files' frame numbers count (CULane's `00030.jpg`: frame 30 of a 30 fps
        /// video, 1 s after `00000.jpg`).
        #[arg(long, default_value_t = 30.0, requires = "frames")]
        fps: f64,
        /// The camera of the images: `culane` (a 1640x590 guess), `tusimple` (1280x720) or a
        /// camera JSON file (any other size: width, height, vp_col, vp_row, height_m,
        /// focal_px). Lane points outside its image are left out; the frames carry it, and
        /// `track` maps their points with it.
        #[arg(long, default_value = "culane", requires = "culane")]
        camera: String,
    },
    /// The demo on bundled data: replay clips (three noise levels, coupled B and diag(B)) and the
    /// 10 real frames through the front end → tracker → official TuSimple metric; prints the
    /// results table and writes overlays and plots.
    Demo {
        /// Output folder for the PNG overlays, plots and results.
        #[arg(long, default_value = "out/demo")]
        out: PathBuf,
        /// The repository's data folder (bundled labels, frames, hyperparameters).
        #[arg(long)]
        data: Option<PathBuf>,
        /// Replay only the first K bundled label clips (default: all 40).
        #[arg(long)]
        clips: Option<usize>,
        /// Replay seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Noise presets of the replay (comma-separated).
        #[arg(long, value_enum, value_delimiter = ',', default_values_t = [NoiseLevel::Low, NoiseLevel::Mid, NoiseLevel::High])]
        noise: Vec<NoiseLevel>,
        /// Frames per replay clip (default 20; the last one is the labelled frame).
        #[arg(long)]
        frames_per_clip: Option<usize>,
        /// Replay labels of the robustness section (clutter × 1, 2, 4, 8, distractors and pixel
        /// noise × 2, × 4, tracker vs the RANSAC baseline; the first K; 0 leaves the section
        /// out).
        #[arg(long, default_value_t = 20)]
        robustness_clips: usize,
        /// Labels of the held-out check (a second generator on the bundled held-out labels,
        /// clutter × 1, 2, 4, 8, segments and column noise × 2, × 4, tracker vs the RANSAC
        /// baseline; the first K of 40; 0 leaves it out).
        #[arg(long, default_value_t = 40)]
        heldout_clips: usize,
        /// Skip the PNG files.
        #[arg(long)]
        no_images: bool,
        /// Print the results as JSON (stdout) instead of tables.
        #[arg(long)]
        json: bool,
    },
    /// Train the spatial kernel, B and the noise (and fit the temporal length-scale) from
    /// TuSimple labels; writes a complete hyperparameter file.
    Train(TrainArgs),
    /// Fit the spatial filter's within-frame row-noise scale (PersistConfig::row_noise_scale)
    /// to labelled lanes by maximum likelihood under the tables' spatial model.
    RowNoise {
        /// TuSimple labels (JSON lines) [default: the checkout's
        /// data/tusimple/train_subset.json, from any working folder].
        #[arg(long, num_args = 1..)]
        labels: Vec<PathBuf>,
        /// Hyperparameter file of the tables [default: the checkout's data/hyper/default.json].
        #[arg(long)]
        hyper: Option<PathBuf>,
        /// Camera of the labels: `tusimple` (the default), `culane` (a 1640x590 guess) or a camera
        /// JSON file with the fields of `Camera` (width, height, vp_col, vp_row, height_m, focal_px).
        #[arg(long)]
        camera: Option<PathBuf>,
        /// Also write the fit (scale, log-likelihoods, profile) as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Real-geometry replay: animate TuSimple labels into 20-frame clips of noisy feature points,
    /// with ground truth for the last frame (and optionally every frame).
    Synth {
        /// TuSimple labels (JSON lines); one clip per label, in order.
        #[arg(long)]
        labels: PathBuf,
        /// Output frames (JSON lines, one frame per line).
        #[arg(long)]
        out: PathBuf,
        /// Output ground truth of each clip's last frame (TuSimple JSON lines). Every frame
        /// names its rows (`h_samples`), so `track` predicts every frame: score those
        /// predictions against this file with `eval --labelled-only` (against `--gt-all`'s as
        /// they are).
        #[arg(long)]
        gt: Option<PathBuf>,
        /// Output ground truth of every frame (TuSimple JSON lines).
        #[arg(long)]
        gt_all: Option<PathBuf>,
        /// Random seed (the output is a function of the labels, parameters and seed).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Use only the first K labels.
        #[arg(long)]
        clips: Option<usize>,
        /// Noise preset (see `stjpdacf_tools::synth`).
        #[arg(long, value_enum, default_value_t = NoiseLevel::Mid)]
        noise: NoiseLevel,
        /// Override the preset's column noise σ, px.
        #[arg(long)]
        pixel_noise: Option<f64>,
        /// Override the preset's per-row detection probability.
        #[arg(long)]
        detect_prob: Option<f64>,
        /// Override the preset's uniform clutter rate, points per frame.
        #[arg(long)]
        clutter_rate: Option<f64>,
        /// Scale of lane drift / heading / curvature change (0 = a static road).
        #[arg(long)]
        motion: Option<f64>,
        /// Mean number of short straight distractor segments per frame (tar seams, arrows,
        /// crosswalk bars; default 0).
        #[arg(long)]
        distractors: Option<f64>,
        /// Camera: `tusimple` (1280x720), `culane` (a 1640x590 guess) or a camera JSON file.
        #[arg(long, default_value = "tusimple")]
        camera: String,
    },
    /// Image front end: IPM to BEV, colour + ridge filtering, ROI, NMS per BEV row; writes the
    /// feature points of every image under a folder as frames (image pixels).
    Frontend {
        /// Folder searched recursively for *.jpg / *.png; raw_file = path relative to it.
        #[arg(long)]
        images: PathBuf,
        /// Output frames (JSON lines).
        #[arg(long)]
        out: PathBuf,
        /// Camera: `tusimple` (the 1280x720 TuSimple camera, scaled by --scale, or to each
        /// image's width when --scale is absent), `culane` (a 1640x590 guess), a camera JSON
        /// file, or `estimate`: each image's horizon, vanishing column and camera height found
        /// from its markings (the focal length from --guess), written into its frame for
        /// `stjpdacf track`.
        #[arg(long, default_value = "tusimple")]
        camera: String,
        /// With `--camera estimate`: the camera to start from (`tusimple`, `culane` or a file),
        /// scaled to each image's width; default: a guess from the first image's size (focal
        /// length 0.8 x width, horizon at 0.4 x height, 1.5 m high).
        #[arg(long)]
        guess: Option<String>,
        /// With `--camera estimate` or `--refine-horizon`: which images share one camera.
        /// `clip` (default): the median of the estimates of a clip's images finds every point
        /// of the clip (what `track` maps the clip with), so an image whose own estimate missed
        /// still gets its clip's BEV; `all`: one camera for every image (one camera, many
        /// drives); `image`: each image's own estimate.
        #[arg(long, value_enum, default_value = "clip")]
        share: ShareArg,
        /// With `--camera estimate` or `--refine-horizon`, and `--share clip|all`: estimate on
        /// the first and every K-th image of a group only (the estimate costs 2–3 ms a 512x288
        /// image).
        #[arg(long, value_name = "K", default_value_t = 1)]
        estimate_every: usize,
        /// With a calibrated camera (`tusimple`, `culane` or a file): move its vanishing point
        /// to where each image's marking lines cross when that is within 1° of the camera's
        /// pitch (the road's grade and the car's pitch change; height and focal length stay),
        /// written into its frame for `stjpdacf track`; costs 2–3 ms a 512x288 image. Shared
        /// as the estimate is (`--share`, `--estimate-every`).
        #[arg(long)]
        refine_horizon: bool,
        /// Frame rate of the image sequences, for the frames' time stamps: a file named `n` is
        /// frame `n` of its clip, counted from 1 (TuSimple: `1.jpg`–`20.jpg` at 20 fps) or from
        /// 0 when the clip has a file named `0`; other names are numbered in order.
        #[arg(long, default_value_t = 20.0)]
        fps: f64,
        /// Front-end parameter overrides `name=value` (the fields of
        /// `stjpdacf_tools::frontend::FrontendParams`, e.g. `ridge_threshold=25`); repeatable.
        #[arg(long = "param", value_name = "NAME=VALUE")]
        params: Vec<String>,
        /// Image scale relative to the camera (0.4 for the 512x288 TuSimple sample).
        #[arg(long)]
        scale: Option<f64>,
        /// TuSimple labels whose h_samples are copied to frames with the same raw_file
        /// (default: IMAGES/label_data.json if it exists).
        #[arg(long)]
        labels: Option<PathBuf>,
        /// Also write a PNG overlay per image (points red, labelled lanes green) into this folder.
        #[arg(long)]
        overlay: Option<PathBuf>,
    },
}

/// The arguments of `stjpdacf train`.
#[derive(clap::Args)]
struct TrainArgs {
    /// TuSimple label files (JSON lines).
    #[arg(long, num_args = 1.., required = true)]
    labels: Vec<PathBuf>,
    /// Output hyperparameter file.
    #[arg(long)]
    out: PathBuf,
    /// Base hyperparameter file (window, D, N and every field not trained) [default: the
    /// checkout's data/hyper/default.json, from any working folder].
    #[arg(long)]
    base: Option<PathBuf>,
    /// L-BFGS starts (the first from the base values, the others random around them).
    #[arg(long, default_value_t = 4)]
    restarts: usize,
    /// Seed of the frame selection and the random starts.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// At most this many frames, evenly spread over the usable ones.
    #[arg(long, default_value_t = 300)]
    max_frames: usize,
    /// Minimum spacing of the points kept per lane, metres.
    #[arg(long, default_value_t = 3.0)]
    spacing: f64,
    /// L-BFGS iterations per start.
    #[arg(long, default_value_t = 300)]
    max_iters: u64,
    /// Per-lane offset variance σ_c² (m²); default: the base file's.
    #[arg(long)]
    offset_variance: Option<f64>,
    /// Train σ_c² as well.
    #[arg(long)]
    train_offset: bool,
    /// Write the fitted temporal length-scale (default: keep the base value, record the fit).
    #[arg(long)]
    fit_temporal: bool,
    /// Cut temporal series where labelled clips are further apart than this, seconds.
    #[arg(long, default_value_t = 10.0)]
    max_gap: f64,
    /// Camera of the labels: `tusimple` (the default), `culane` (a 1640x590 guess) or a camera
    /// JSON file with the fields of `Camera` (width, height, vp_col, vp_row, height_m, focal_px).
    #[arg(long)]
    camera: Option<PathBuf>,
    /// Write a report (B heat map PNG, summary.json, summary.md) into this folder.
    #[arg(long)]
    report: Option<PathBuf>,
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::Tables { hyper, out, name } => {
            let hyper = hyper.unwrap_or_else(|| stjpdacf_tools::bundled(tablegen::DEFAULT_HYPER));
            // The generated file names its source as given, one in the checkout by its path there.
            let origin = stjpdacf_tools::shown_path(&hyper);
            let h = HyperFile::load(&hyper)?;
            let t = tablegen::ModelTables::from_hyper(&h)?;
            let src = tablegen::render(&t, &name, &origin)?;
            if out.as_os_str() == "-" {
                print!("{src}");
            } else {
                stjpdacf_tools::write_output(&out, &src)?;
                eprintln!(
                    "wrote {} (NT = {}, LANES = {}, POINTS = {}, Gram rank {} of {})",
                    out.display(),
                    h.spatial.order,
                    h.lanes(),
                    h.index_points,
                    t.gram_rank,
                    h.index_points
                );
            }
        }
        Command::Track {
            frames,
            out,
            hyper,
            camera,
            scale,
            space,
            export_points,
            interval_evidence,
            decisive_rays_only,
            no_slot_claims,
            lane_width,
            no_own_pd,
            no_newcomer_wait,
            newcomer_wait,
            row_noise_scale,
            baseline,
            overlay,
            images,
            labels,
            every_frame,
            lanes,
            model,
        } => {
            let model = match model {
                ModelArg::Reference => stjpdacf_tools::track::Model::Reference,
                ModelArg::Rank5 => stjpdacf_tools::track::Model::Rank5,
                ModelArg::Small => stjpdacf_tools::track::Model::Small,
                ModelArg::Rank3 => stjpdacf_tools::track::Model::Rank3,
            };
            anyhow::ensure!(
                hyper.is_none()
                    || !matches!(
                        model,
                        stjpdacf_tools::track::Model::Small | stjpdacf_tools::track::Model::Rank3
                    ),
                "--model small and rank3 run the built-in uncoupled tables: leave out --hyper"
            );
            let tables: &'static stjpdacf::tables::ReferenceTables = model.tables(match hyper {
                Some(p) => stjpdacf_tools::track::tables_from_hyper(&HyperFile::load(&p)?)?,
                None => &stjpdacf::tables::DEFAULT,
            });
            anyhow::ensure!(
                lane_width >= 0.0 && lane_width.is_finite(),
                "--lane-width must be finite and ≥ 0 (metres; 0 publishes every line structure), \
                 not {lane_width}"
            );
            if let Some(r) = row_noise_scale {
                anyhow::ensure!(
                    r > 0.0 && r.is_finite(),
                    "--row-noise-scale must be a finite number > 0, not {r:?}"
                );
            }
            let cam = Camera::from_spec(&camera)?;
            let cam = match scale {
                Some(s) => {
                    anyhow::ensure!(
                        s > 0.0 && s.is_finite(),
                        "--scale must be a finite number > 0, not {s:?}"
                    );
                    cam.scaled(s)
                }
                None => cam,
            };
            let frames_path = frames;
            let mut frames = tusimple::read_frames(&frames_path)?;
            anyhow::ensure!(
                !frames.is_empty(),
                "{}: no frames (JSON lines of clip, t, points)",
                frames_path.display()
            );
            if every_frame {
                stjpdacf_tools::track::predict_every_frame(&mut frames, &cam);
                // Every frame is predicted now: a raw_file that names two frames would name
                // two predictions (the scorer joins on it).
                let mut named = std::collections::HashMap::new();
                for (k, f) in frames.iter().enumerate() {
                    let Some(raw) = f.raw_file.as_deref() else {
                        continue;
                    };
                    if let Some(first) = named.insert(raw, k) {
                        anyhow::bail!(
                            "{}: raw_file {raw} names frames {} and {} (counted from 1); \
                             --every-frame writes a prediction for every frame, so each needs its \
                             own raw_file (or none: it is then named clip/k)",
                            frames_path.display(),
                            first + 1,
                            k + 1
                        );
                    }
                }
            }
            let unlabelled = frames
                .iter()
                .filter(|f| f.h_samples.is_none() || f.raw_file.is_none())
                .count();
            // The frames' own camera when they all carry one and the same (`frontend` with a
            // calibration): it maps them, whatever --camera and --scale say.
            let own_camera = frames
                .first()
                .and_then(|f| f.camera)
                .filter(|c| frames.iter().all(|f| f.camera == Some(*c)));
            if let Some(c) = own_camera.filter(|c| *c != cam) {
                if scale.is_some() || camera != "tusimple" {
                    eprintln!(
                        "note: the frames carry the camera their points were found with \
                         ({}x{}, horizon row {:.1}, written by `frontend` or `convert`): they are \
                         mapped with it, not with --camera / --scale (write them again to change it)",
                        c.width, c.height, c.vp_row
                    );
                }
            }
            anyhow::ensure!(
                export_points.is_none()
                    || own_camera.is_some()
                    || frames.iter().all(|f| f.camera.is_none()),
                "--export-points writes one camera for all frames; these frames carry cameras \
                 that differ (from `frontend --camera estimate` or --refine-horizon): track them \
                 without --export-points"
            );
            let cam = own_camera.unwrap_or(cam);
            let bar = indicatif::ProgressBar::new(frames.len() as u64);
            let space = match space {
                SpaceArg::Image => stjpdacf_tools::track::Space::Image,
                SpaceArg::Bev => stjpdacf_tools::track::Space::Bev,
            };
            if let Some(max_lanes) = baseline {
                anyhow::ensure!(
                    frames.iter().all(|f| f.camera.is_none()) || own_camera.is_some(),
                    "--baseline maps every frame with one camera; these frames carry cameras \
                     that differ (from `frontend --camera estimate` or --refine-horizon)"
                );
                anyhow::ensure!(
                    export_points.is_none() && overlay.is_none() && lanes.is_none(),
                    "--baseline writes predictions only (no --export-points, --overlay, --lanes)"
                );
                let d = stjpdacf_tools::baseline::BaselineParams::default();
                let params = stjpdacf_tools::baseline::BaselineParams {
                    max_lanes: if max_lanes == 0 {
                        d.max_lanes
                    } else {
                        max_lanes
                    },
                    ..d
                };
                let (preds, stats) =
                    stjpdacf_tools::baseline::track(&frames, tables, &cam, space, &params, |k| {
                        bar.set_position(k as u64 + 1)
                    })?;
                bar.finish_and_clear();
                tusimple::write_records(&out, &preds)?;
                eprintln!(
                    "{} frames in {} clips, {} predictions of the per-frame RANSAC baseline (no \
                     tracking) to {}; fit {:.3} ms mean, {:.3} ms max of CPU time",
                    stats.frames,
                    stats.clips,
                    stats.predictions,
                    out.display(),
                    stats.step_mean_ms,
                    stats.step_max_ms
                );
                return Ok(());
            }
            let mut export = match &export_points {
                Some(p) => {
                    let mut w = std::io::BufWriter::new(stjpdacf_tools::create_output(p)?);
                    stjpdacf_tools::track::write_points_header(&mut w, &cam)
                        .with_context(|| format!("writing {}", p.display()))?;
                    Some(w)
                }
                None => None,
            };
            let mut overlays = match (&overlay, &images) {
                (Some(dir), Some(images)) => {
                    let labels = match &labels {
                        Some(p) => tusimple::read_labels(p)?,
                        None => Vec::new(),
                    };
                    Some(stjpdacf_tools::demo::OverlayWriter::new(
                        images, dir, cam, space, tables, labels,
                    )?)
                }
                _ => None,
            };
            let mut lanes_out = match &lanes {
                Some(p) => Some(std::io::BufWriter::new(stjpdacf_tools::create_output(p)?)),
                None => None,
            };
            let mut lanes_err: Option<anyhow::Error> = None;
            let mut lanes_rec = stjpdacf_tools::track::LanesRecorder::default();
            let mut overlay_err = None;
            let (mut clip_no, mut last_clip, mut export_err) = (0usize, None::<String>, None);
            let (preds, stats) = stjpdacf_tools::track::track_with(
                &frames,
                tables,
                &cam,
                space,
                model.config({
                    let d = stjpdacf::tracker::TrackerConfig::DEFAULT;
                    stjpdacf::tracker::TrackerConfig {
                        persist: stjpdacf::persist::PersistConfig {
                            paint_gap: if interval_evidence {
                                None
                            } else {
                                d.persist.paint_gap
                            },
                            ray_aligned: d.persist.ray_aligned && !decisive_rays_only,
                            slot_claims: d.persist.slot_claims && !no_slot_claims,
                            lane_width,
                            own_pd: d.persist.own_pd && !no_own_pd,
                            newcomer_wait: if no_newcomer_wait {
                                0
                            } else {
                                newcomer_wait.unwrap_or(d.persist.newcomer_wait)
                            },
                            row_noise_scale: row_noise_scale.unwrap_or(d.persist.row_noise_scale),
                            ..d.persist
                        },
                        ..d
                    }
                }),
                |v| {
                    bar.set_position(v.index as u64 + 1);
                    if let (Some(w), None) = (lanes_out.as_mut(), &lanes_err) {
                        let rec = lanes_rec.record(&v, tables);
                        if let Err(e) = tusimple::write_jsonl_to(&mut *w, &[rec]) {
                            lanes_err = Some(e);
                        }
                    }
                    if let Some(o) = overlays.as_mut() {
                        if overlay_err.is_none() {
                            if let Err(e) = o.frame(&v) {
                                overlay_err = Some(e);
                            }
                        }
                    }
                    let Some(w) = export.as_mut() else { return };
                    if last_clip.as_deref() != Some(v.frame.clip.as_str()) {
                        clip_no += 1;
                        last_clip = Some(v.frame.clip.clone());
                    }
                    if let Err(e) = stjpdacf_tools::track::write_points_frame(w, clip_no, &v) {
                        export_err.get_or_insert(e);
                    }
                },
            )?;
            bar.finish_and_clear();
            if let (Some(e), Some(p)) = (export_err, &export_points) {
                return Err(e).with_context(|| format!("writing the points file {}", p.display()));
            }
            if let Some(e) = overlay_err {
                return Err(e).context("drawing the overlays");
            }
            if let (Some(e), Some(p)) = (lanes_err, &lanes) {
                return Err(e).with_context(|| format!("writing {}", p.display()));
            }
            if let (Some(o), Some(dir)) = (&overlays, &overlay) {
                eprintln!(
                    "{} overlays to {} ({} frames without an image)",
                    o.written.len(),
                    dir.display(),
                    o.skipped
                );
            }
            if let (Some(mut w), Some(p)) = (export, &export_points) {
                std::io::Write::flush(&mut w)
                    .with_context(|| format!("writing {}", p.display()))?;
            }
            tusimple::write_records(&out, &preds)?;
            eprintln!(
                "{} frames in {} clips, {} predictions to {}; run_time {:.3} ms mean, {:.3} ms max (wall clock; Tracker::step {:.3} / {:.3} ms of CPU time); {} points above the horizon or non-finite; {} steps rejected",
                stats.frames, stats.clips, stats.predictions, out.display(), stats.run_mean_ms, stats.run_max_ms, stats.step_mean_ms, stats.step_max_ms, stats.unmapped_points, stats.rejected_steps
            );
            if stats.frames > 0 {
                eprintln!(
                    "lane ids per clip {:.2}, lanes published per frame {:.2} (lanes missed on at \
                     most {MAX_REPORT_MISSES} frames in a row; a road's markings, each keeping its id, \
                     give as many ids a clip as lanes a frame)",
                    stats.lane_ids as f64 / stats.clips.max(1) as f64,
                    stats.published_lanes as f64 / stats.frames as f64,
                );
            }
            let n_points: usize = frames.iter().map(|f| f.points.len()).sum();
            if stats.published_lanes == 0
                && n_points > 0
                && space == stjpdacf_tools::track::Space::Image
            {
                let need = usize::from(
                    stjpdacf::tracker::TrackerConfig::DEFAULT
                        .identity
                        .min_common
                        .max(1),
                );
                let step = f64::from(tables.index_u[1] - tables.index_u[0]);
                if let Some((row, u)) = stjpdacf_tools::track::lane_reach_needed(&cam, tables, need)
                {
                    eprintln!(
                        "warning: no lane was published. A lane is tracked from {need} index \
                         points up (every {:.1} m from {} m ahead): seen from the bottom of the \
                         {}x{} image of this camera, a lane must reach row {row:.0} ({u:.1} m \
                         ahead). Check that the lanes' points reach that far and that the camera \
                         is the images' (horizon row {:.1})",
                        step, tables.hyper.u_min, cam.width, cam.height, cam.vp_row
                    );
                }
            }
            if 2 * stats.unmapped_points > n_points {
                eprintln!(
                    "warning: {} of the {n_points} points lie at or above the horizon of the \
                     camera they were tracked with ({}x{}, horizon row {:.1}, unless a frame \
                     carries its own): points of a smaller image need --scale (0.4 for 512x288 \
                     frames of TuSimple's camera), points of another camera its --camera, and \
                     BEV points (metres, [x, u]) --space bev",
                    stats.unmapped_points, cam.width, cam.height, cam.vp_row
                );
            }
            if 2 * stats.outside_window_points > n_points {
                eprintln!(
                    "warning: {} of the {n_points} points lie outside the tracker's window \
                     ({:.0}–{:.0} m ahead), so it ignores them: BEV points are [x lateral, u \
                     ahead] in metres (--space bev), image points [column, row] in pixels \
                     (--space image, the default)",
                    stats.outside_window_points, tables.hyper.u_min, tables.hyper.u_max
                );
            }
            if stats.over_budget_points > 0 {
                eprintln!(
                    "({} points on {} frames left out to fit the core's budgets of {} points a \
                     frame and {} a BEV row after preprocessing: in the fullest rows, those \
                     farthest from the car laterally; `track::fit_budget`)",
                    stats.over_budget_points,
                    stats.over_budget_frames,
                    stjpdacf_tools::track::POINT_BUDGET,
                    stjpdacf_tools::track::ROW_BUDGET
                );
            }
            if stats.outside_image_points > 0 {
                eprintln!(
                    "warning: {} image points lie outside the image of the camera they were \
                     tracked with ({}x{} unless a frame carries its own): they were found with \
                     another camera or image size, so their road positions are wrong (give \
                     `track` the front end's --camera, and --scale for a resized image; frames \
                     that carry a camera, from `frontend` or `convert`, are mapped with it: \
                     write them again with the right --camera)",
                    stats.outside_image_points, cam.width, cam.height
                );
            }
            if stats.outside_image_rows > 0 {
                eprintln!(
                    "warning: {} label rows (h_samples) lie outside the image of the camera the \
                     frames were tracked with ({}x{} unless a frame carries its own), so the \
                     predictions are -2 there: labels of another image size (scale the \
                     h_samples to the frames' images, or give --scale)",
                    stats.outside_image_rows, cam.width, cam.height
                );
            }
            if unlabelled > 0 {
                eprintln!(
                    "({unlabelled} frames without h_samples rows or raw_file got no prediction; \
                     --every-frame writes one for every frame)"
                );
            }
            if stats.repaired_frames > 0 {
                eprintln!(
                    "({} frames with a repair of the f32 temporal covariance: rounding had made \
                     it indefinite, docs/design.md §4.2.4; frequent on near-identical frames, \
                     a stopped vehicle, see Known limits in the README)",
                    stats.repaired_frames
                );
            }
        }
        Command::Kernels => {
            print!(
                "{}",
                stjpdacf_reference::statespace::approximation_table(2..=6)
            );
        }
        Command::Eval {
            pred,
            gt,
            json,
            pixel_scale,
            per_frame,
            per_lane,
            labelled_only,
            metric: which,
            lane_px,
            iou,
            image_size,
        } => {
            anyhow::ensure!(
                pixel_scale > 0.0 && pixel_scale.is_finite(),
                "--pixel-scale must be a finite number > 0, not {pixel_scale:?}"
            );
            // Read and checked once for the score and both lists.
            let (preds, gts, left_out) =
                metric::read_scaled(&pred, &gt, pixel_scale, labelled_only)?;
            if labelled_only {
                eprintln!(
                    "{} predictions of labelled frames scored, {left_out} of unlabelled frames left out",
                    preds.len()
                );
            }
            if which == MetricArg::Culane {
                anyhow::ensure!(
                    per_frame.is_none() && per_lane.is_none(),
                    "--per-frame and --per-lane list the TuSimple metric's scores: leave them out \
                     with --metric culane"
                );
                anyhow::ensure!(
                    lane_px > 0.0 && lane_px.is_finite() && (0.0..1.0).contains(&iou),
                    "--lane-px must be a positive width and --iou in [0, 1)"
                );
                let size = image_size
                    .split_once('x')
                    .and_then(|(w, h)| Some((w.parse::<usize>().ok()?, h.parse::<usize>().ok()?)))
                    .filter(|&(w, h)| w > 0 && h > 0 && w * h <= 100_000_000)
                    .with_context(|| {
                        format!("--image-size {image_size:?}: give WxH, e.g. 1640x590")
                    })?;
                let s = stjpdacf_tools::culane::f1_score(&preds, &gts, lane_px, iou, size)?;
                if json {
                    println!("{}", serde_json::to_string(&s)?);
                } else {
                    println!(
                        "CULane metric ({} frames, {lane_px} px lanes, IoU > {iou}, {}x{})",
                        gts.len(),
                        size.0,
                        size.1
                    );
                    println!("  TP {}  FP {}  FN {}", s.tp, s.fp, s.fn_);
                    println!("  Precision {:.6}", s.precision);
                    println!("  Recall    {:.6}", s.recall);
                    println!("  F1        {:.6}", s.f1);
                }
                return Ok(());
            }
            let (s, mut frames) = metric::score_frames(&preds, &gts, (&pred, &gt))?;
            if let Some(p) = &per_frame {
                // Worst first: accuracy up, then FP + FN down; ties in file order.
                frames.sort_by(|a, b| {
                    a.accuracy
                        .total_cmp(&b.accuracy)
                        .then((b.fp + b.fn_).total_cmp(&(a.fp + a.fn_)))
                });
                tusimple::write_jsonl(p, &frames)?;
                eprintln!(
                    "{} frame scores to {}; the worst:",
                    frames.len(),
                    p.display()
                );
                for f in frames.iter().take(5) {
                    eprintln!(
                        "  {}: accuracy {:.3}, FP {:.3}, FN {:.3} ({} / {} lanes predicted / labelled){}",
                        f.raw_file,
                        f.accuracy,
                        f.fp,
                        f.fn_,
                        f.pred_lanes,
                        f.gt_lanes,
                        if f.penalty { ", penalty" } else { "" }
                    );
                }
            }
            if let Some(p) = &per_lane {
                let lanes = metric::frame_lane_rows(&preds, &gts);
                tusimple::write_jsonl(p, &lanes)?;
                let lost: Vec<&metric::LaneRows> = lanes
                    .iter()
                    .map(|l| &l.lane)
                    .filter(|l| !l.matched && l.labelled() > 0)
                    .collect();
                let misplaced = lost.iter().filter(|l| l.misplaced()).count();
                eprintln!(
                    "{} labelled lanes to {}; {} with points unmatched: {} not found (mostly \
                     missing rows, or the nearest prediction is another lane's), {} found and \
                     drawn in the wrong place (mostly off or extra rows)",
                    lanes.len(),
                    p.display(),
                    lost.len(),
                    lost.len() - misplaced,
                    misplaced
                );
            }
            if json {
                println!(
                    "{}",
                    serde_json::to_string(&s).context("serialising the score")?
                );
            } else {
                println!("TuSimple metric ({} frames)", s.frames);
                println!("  Accuracy  {:.6}", s.accuracy);
                println!("  FP        {:.6}", s.fp);
                println!("  FN        {:.6}", s.fn_);
            }
        }
        Command::RowNoise {
            labels,
            hyper,
            camera,
            json,
        } => {
            let camera = match camera {
                Some(p) => Camera::from_spec(&p.to_string_lossy())?,
                None => Camera::tusimple(),
            };
            let hyper = hyper.unwrap_or_else(|| stjpdacf_tools::bundled(tablegen::DEFAULT_HYPER));
            let labels = if labels.is_empty() {
                vec![stjpdacf_tools::bundled("data/tusimple/train_subset.json")]
            } else {
                labels
            };
            let tables = stjpdacf_reference::model::ModelTables::from_hyper(
                &stjpdacf_reference::hyper::HyperFile::load(&hyper)?,
            )?;
            let mut frames = Vec::new();
            for p in &labels {
                frames.extend(stjpdacf_tools::train::read_labels(p)?);
                warn_labels_off_camera(p, &camera);
            }
            let lanes = rownoise::label_lanes(&frames, &camera, &tables);
            let fit = rownoise::fit(&rownoise::RowModel::from_tables(&tables), &lanes)?;
            for (s, ll) in &fit.profile {
                println!("  s = {s:<10.4} log-likelihood {ll:.1}");
            }
            println!(
                "row_noise_scale = {:.4} (log-likelihood {:.1}; {:.1} at s = 1): {} lanes, {} points of {} label frames",
                fit.scale,
                fit.log_likelihood,
                fit.log_likelihood_unscaled,
                fit.lanes,
                fit.points,
                frames.len()
            );
            if let Some(p) = json {
                stjpdacf_tools::write_output(&p, serde_json::to_string_pretty(&fit)? + "\n")?;
            }
        }
        Command::Train(a) => {
            let camera = match a.camera {
                Some(p) => Camera::from_spec(&p.to_string_lossy())?,
                None => Camera::tusimple(),
            };
            for p in &a.labels {
                warn_labels_off_camera(p, &camera);
            }
            let (out, report, restarts) = (a.out, a.report, a.restarts);
            let opts = trainrun::TrainOptions {
                labels: a.labels,
                base: a
                    .base
                    .unwrap_or_else(|| stjpdacf_tools::bundled(tablegen::DEFAULT_HYPER)),
                camera,
                restarts,
                seed: a.seed,
                max_frames: a.max_frames,
                spacing: a.spacing,
                max_iters: a.max_iters,
                offset_variance: a.offset_variance,
                train_offset: a.train_offset,
                use_fitted_temporal: a.fit_temporal,
                max_gap: a.max_gap,
            };
            let bar = indicatif::ProgressBar::new(restarts as u64);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "{spinner} [{elapsed_precise}] start {pos}/{len} {wide_msg}",
                )
                .context("progress template")?,
            );
            let progress = |start: usize, evals: usize, lml: f64| {
                bar.set_position(start as u64);
                bar.set_message(format!("evaluation {evals}, LML {lml:.3}"));
                bar.tick();
            };
            let outcome = trainrun::run(&opts, &progress)?;
            bar.finish_and_clear();
            let text = serde_json::to_string_pretty(&outcome.hyper)? + "\n";
            stjpdacf_tools::write_output(&out, text)?;
            let p = &outcome.fit.params;
            eprintln!(
                "wrote {}: {} frames, LML {:.3}, ℓ_u = {:.3} m, noise = {:.5} m², σ_c² = {:.3} m²",
                out.display(),
                outcome.frames_used,
                outcome.fit.lml,
                p.lengthscale,
                p.noise,
                p.offset_variance
            );
            eprintln!("B =\n{:.3}", p.b());
            eprintln!(
                "stationary B profile (|i−j| = 0..): {:.3?}",
                stjpdacf_tools::train::stationary_profile(&p.b())
            );
            if let Some(dir) = report {
                let cmd = std::env::args().collect::<Vec<_>>().join(" ");
                trainrun::write_report(&dir, &outcome, &cmd)?;
                eprintln!("report in {}", dir.display());
            }
        }
        Command::Convert {
            culane,
            to_culane,
            out,
            frames,
            labels,
            row_step,
            fps,
            camera,
        } => {
            if let Some(dir) = culane {
                convert_culane(
                    &dir,
                    &out,
                    frames.as_deref(),
                    labels.as_deref(),
                    row_step,
                    fps,
                    &camera,
                )?;
            } else if let Some(file) = to_culane {
                let records: Vec<tusimple::TuSimpleRecord> = tusimple::read_jsonl(&file)?;
                for r in &records {
                    let path = stjpdacf_tools::culane::lane_file_of(&out, &r.raw_file)?;
                    if let Some(d) = path.parent() {
                        std::fs::create_dir_all(d)
                            .with_context(|| format!("creating folder {}", d.display()))?;
                    }
                    std::fs::write(&path, stjpdacf_tools::culane::lines_text(r))
                        .with_context(|| format!("writing {}", path.display()))?;
                }
                eprintln!("{} lane files under {}", records.len(), out.display());
            }
        }
        Command::Synth {
            labels,
            out,
            gt,
            gt_all,
            seed,
            clips,
            noise,
            pixel_noise,
            detect_prob,
            clutter_rate,
            motion,
            distractors,
            camera,
        } => {
            let cam = Camera::from_spec(&camera)?;
            let mut params = SynthParams::preset(noise);
            if let Some(v) = pixel_noise {
                params.pixel_noise = v;
            }
            if let Some(v) = detect_prob {
                params.detect_prob = v;
            }
            if let Some(v) = clutter_rate {
                params.clutter_rate = v;
            }
            if let Some(v) = motion {
                params.motion = v;
            }
            if let Some(v) = distractors {
                params.distractors = v;
            }
            let mut recs = tusimple::read_labels(&labels)?;
            if let Some(k) = clips {
                anyhow::ensure!(k > 0, "--clips must be at least 1 (one clip a label)");
                recs.truncate(k);
            }
            anyhow::ensure!(!recs.is_empty(), "{}: no labels", labels.display());
            if let Some(w) =
                stjpdacf_tools::track::labels_off_camera_warning(&recs, &cam, "--camera")
            {
                eprintln!("{w}");
            }
            let bar = indicatif::ProgressBar::new(recs.len() as u64);
            let o = synth::synthesize_with_progress(&recs, &params, &cam, seed, || bar.inc(1))
                .with_context(|| format!("synthesising from {}", labels.display()))?;
            bar.finish_and_clear();
            tusimple::write_frames(&out, &o.frames)?;
            if let Some(p) = &gt {
                tusimple::write_records(p, &o.gt_last)?;
            }
            if let Some(p) = &gt_all {
                tusimple::write_records(p, &o.gt_all)?;
            }
            let s = &o.stats;
            eprintln!(
                "wrote {} frames of {} clips to {} ({} points: {} lane, {} clutter, {} shadow, {} car, {} road edge, {} distractor; {} lane changes, {} merges, {} far-end changes)",
                s.frames,
                s.clips,
                out.display(),
                s.total_points(),
                s.lane_points,
                s.clutter_points,
                s.shadow_points,
                s.car_points,
                s.road_edge_points,
                s.distractor_points,
                s.lane_changes,
                s.merges,
                s.far_end_changes
            );
        }
        Command::Frontend {
            images,
            out,
            camera,
            guess,
            share,
            estimate_every,
            refine_horizon,
            fps,
            params,
            scale,
            labels,
            overlay,
        } => {
            let mut p = frontend::FrontendParams {
                fps,
                ..Default::default()
            };
            for a in &params {
                let (name, v) = a
                    .split_once('=')
                    .with_context(|| format!("--param {a}: expected NAME=VALUE"))?;
                let v: f64 = v
                    .parse()
                    .with_context(|| format!("--param {a}: {v} is not a number"))?;
                p.set(name, v)?;
            }
            let scaled = |c: Camera| -> Result<Camera> {
                Ok(match scale {
                    Some(s) => {
                        anyhow::ensure!(
                            s > 0.0 && s.is_finite(),
                            "--scale must be a finite number > 0, not {s:?}"
                        );
                        c.scaled(s)
                    }
                    None => c,
                })
            };
            anyhow::ensure!(
                guess.is_none() || camera == "estimate",
                "--guess is the starting point of --camera estimate"
            );
            anyhow::ensure!(
                estimate_every >= 1 && (share != ShareArg::Image || estimate_every == 1),
                "--estimate-every must be at least 1, and 1 with --share image"
            );
            anyhow::ensure!(
                camera == "estimate"
                    || refine_horizon
                    || (share == ShareArg::Clip && estimate_every == 1),
                "--share and --estimate-every go with --camera estimate or --refine-horizon"
            );
            anyhow::ensure!(
                !(refine_horizon && camera == "estimate"),
                "--refine-horizon refines a calibrated camera; --camera estimate finds the whole \
                 vanishing point already"
            );
            // The estimate (`--camera estimate`) or the refinement (`--refine-horizon`) from
            // `start`, on each image or shared (`--share`, `--estimate-every`).
            let fitted_mode = |start: Camera, fit: frontend::Fit| {
                let shared = |share| frontend::CameraMode::EstimateShared {
                    guess: start,
                    share,
                    every: estimate_every,
                    fit,
                };
                match (share, fit) {
                    (ShareArg::Image, frontend::Fit::Camera) => {
                        frontend::CameraMode::Estimate(start)
                    }
                    (ShareArg::Image, frontend::Fit::Horizon) => {
                        frontend::CameraMode::Refine(start)
                    }
                    (ShareArg::Clip, _) => shared(frontend::Share::Clip),
                    (ShareArg::All, _) => shared(frontend::Share::All),
                }
            };
            let mode = match (camera.as_str(), scale) {
                ("estimate", _) => fitted_mode(
                    match &guess {
                        Some(spec) => scaled(Camera::from_spec(spec)?)?,
                        None => {
                            let first = frontend::find_images(&images)?
                                .into_iter()
                                .next()
                                .with_context(|| {
                                    format!("no *.jpg or *.png images under {}", images.display())
                                })?;
                            let (w, h) = image::image_dimensions(&first)
                                .with_context(|| format!("{}", first.display()))?;
                            Camera::guess(f64::from(w), f64::from(h))
                        }
                    },
                    frontend::Fit::Camera,
                ),
                // The calibration (`tusimple` scaled to each image when --scale is absent).
                (spec, _) if refine_horizon => {
                    fitted_mode(scaled(Camera::from_spec(spec)?)?, frontend::Fit::Horizon)
                }
                ("tusimple", None) => frontend::CameraMode::TuSimple,
                (spec, _) => frontend::CameraMode::Given(scaled(Camera::from_spec(spec)?)?),
            };
            let labels = labels.or_else(|| {
                let p = images.join("label_data.json");
                p.exists().then_some(p)
            });
            let recs = match &labels {
                Some(p) => tusimple::read_labels(p)?,
                None => Vec::new(),
            };
            if let (Some(p), true) = (&labels, recs.is_empty()) {
                eprintln!(
                    "warning: {}: no labels, so no frame has h_samples (`track` writes no \
                     prediction for them)",
                    p.display()
                );
            }
            let bar = indicatif::ProgressBar::hidden();
            let start = std::time::Instant::now();
            let frames = frontend::run_dir_cameras(&images, &mode, &recs, &p, |k, n| {
                if k == 1 {
                    bar.set_length(n as u64);
                    bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
                }
                bar.set_position(k as u64);
            })?;
            let wall_ms = start.elapsed().as_secs_f64() * 1e3;
            let front_ms: f64 = frames.iter().map(|(_, ms, _)| ms).sum();
            let frames = frames.into_iter().map(|(f, _, _)| f).collect::<Vec<_>>();
            bar.finish_and_clear();
            tusimple::write_frames(&out, &frames)?;
            if let (Some(note), Some(p)) =
                (frontend::unmatched_labels_note(&frames, &recs), &labels)
            {
                eprintln!("warning: {}: {note}", p.display());
            }
            if let Some(dir) = &overlay {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("creating {}", dir.display()))?;
                for f in &frames {
                    let raw = f.raw_file.as_deref().unwrap_or_default();
                    let png = dir.join(format!("{}.png", raw.replace('/', "_")));
                    let label = recs.iter().find(|l| l.raw_file == raw);
                    frontend::overlay_png(&images.join(raw), &f.points, label, &png)?;
                }
                eprintln!("wrote overlays to {}", dir.display());
            }
            let n_pts: usize = frames.iter().map(|f| f.points.len()).sum();
            eprintln!(
                "wrote {} frames ({} feature points; front end {:.1} ms per image, {:.1} ms with \
                 reading and decoding the file) to {}",
                frames.len(),
                n_pts,
                front_ms / frames.len() as f64,
                wall_ms / frames.len() as f64,
                out.display()
            );
            if camera == "estimate" || refine_horizon {
                print_estimated_cameras(&frames, share != ShareArg::Image, refine_horizon);
            }
        }
        Command::Demo {
            out,
            data,
            clips,
            seed,
            noise,
            frames_per_clip,
            robustness_clips,
            heldout_clips,
            no_images,
            json,
        } => {
            let mut opts = demo::DemoOptions {
                out,
                clips,
                seed,
                levels: noise,
                frames_per_clip,
                robustness_clips,
                heldout_clips,
                images: !no_images,
                ..demo::DemoOptions::default()
            };
            if let Some(d) = data {
                opts.data = d;
            }
            let bar = indicatif::ProgressBar::new(1);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {wide_msg}",
                )
                .context("progress template")?,
            );
            let report = demo::run(&opts, |k, n, what| {
                bar.set_length(n as u64);
                bar.set_position(k as u64);
                bar.set_message(what.to_string());
            })?;
            bar.finish_and_clear();
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&report).context("serialising the report")?
                );
            } else {
                print!("{}", demo::render_markdown(&report));
                println!(
                    "\nwrote {} files to {} in {:.1} s:",
                    report.files.len(),
                    opts.out.display(),
                    report.wall_s
                );
                for f in &report.files {
                    println!("  {}", f.display());
                }
            }
        }
    }
    Ok(())
}

/// Warns when the labels of `path` do not fit `camera` (`track::labels_off_camera`); a file
/// the TuSimple reader refuses is left to the command's own reader to report.
fn warn_labels_off_camera(path: &std::path::Path, camera: &Camera) {
    let Ok(recs) = tusimple::read_labels(path) else {
        return;
    };
    if let Some(w) = stjpdacf_tools::track::labels_off_camera_warning(&recs, camera, "--camera") {
        eprintln!("{}: {w}", path.display());
    }
}

/// For `frontend --camera estimate`: the estimated cameras in one line (median and range of the
/// horizon row, the vanishing column and the height), and how many frames' horizons lie more
/// than 2 % of the image height from their clip's camera (`track::clip_camera`, what `track`
/// maps the clip with): single-frame misses of the estimate. With `shared` estimates (`--share
/// clip|all`) every frame carries its group's camera, and the misses are not counted. `refined`:
/// the cameras are a calibration's, refined (`--refine-horizon`).
fn print_estimated_cameras(frames: &[tusimple::Frame], shared: bool, refined: bool) {
    let cams: Vec<Camera> = frames.iter().filter_map(|f| f.camera).collect();
    if cams.is_empty() {
        return;
    }
    let stats = |field: fn(&Camera) -> f64| {
        let mut v: Vec<f64> = cams.iter().map(field).collect();
        v.sort_by(f64::total_cmp);
        (v[v.len() / 2], v[0], v[v.len() - 1])
    };
    let (r, r0, r1) = stats(|c| c.vp_row);
    let (c, c0, c1) = stats(|c| c.vp_col);
    let (h, h0, h1) = stats(|c| c.height_m);
    let misses = if shared {
        format!(
            "{} frames, each with its group's camera (the median of the group's estimates)",
            cams.len()
        )
    } else {
        let far: usize = tusimple::clips(frames)
            .map(|clip_frames| {
                let cc = stjpdacf_tools::track::clip_camera(clip_frames, &cams[0]);
                clip_frames
                    .iter()
                    .filter_map(|f| f.camera)
                    .filter(|k| (k.vp_row - cc.vp_row).abs() > 0.02 * k.height)
                    .count()
            })
            .sum();
        format!(
            "{far} of {} frames with a horizon more than 2 % of the height from their clip's \
             median (single-frame misses; `track` maps each clip with the median)",
            cams.len()
        )
    };
    eprintln!(
        "{} cameras: horizon row {r:.1} (median; {r0:.1}–{r1:.1}), vanishing column {c:.1} \
         ({c0:.1}–{c1:.1}), height {h:.2} m ({h0:.2}–{h1:.2}), focal length {:.0} px ({}); \
         {misses}",
        if refined { "refined" } else { "estimated" },
        cams[0].focal_px,
        if refined {
            "the calibration's"
        } else {
            "the guess's"
        },
    );
}

/// `convert --culane`: lane files to TuSimple records (and frames), with what was left out and
/// how the files were matched and timed said on stderr.
fn convert_culane(
    dir: &std::path::Path,
    out: &std::path::Path,
    frames: Option<&std::path::Path>,
    labels: Option<&std::path::Path>,
    row_step: f64,
    fps: f64,
    camera: &str,
) -> Result<()> {
    use stjpdacf_tools::culane;
    // Every argument checked before anything is written.
    let cam = Camera::from_spec(camera)?;
    anyhow::ensure!(
        fps.is_finite() && fps > 0.0,
        "--fps must be a positive number, not {fps}"
    );
    let labels: Option<Vec<tusimple::TuSimpleRecord>> =
        labels.map(tusimple::read_labels).transpose()?;
    let (mut records, rep) = culane::read_dir(dir, row_step, &cam, labels.as_deref())?;
    if let Some(l) = &labels {
        anyhow::ensure!(
            rep.labelled > 0,
            "none of the {} images under {} is in the {} labels (e.g. {} is not): a raw_file \
             is the image's path relative to the folder given to --culane, so convert the \
             labels and these files from folders at the same level (labels/driver_x/… and \
             detections/driver_x/…)",
            rep.files,
            dir.display(),
            l.len(),
            records.first().map_or("", |r| r.raw_file.as_str())
        );
        if let Some(e) = &rep.unlabelled_example {
            eprintln!(
                "note: {} of the {} images are not in the labels (e.g. {e}): their frames get \
                 no prediction",
                rep.files - rep.labelled,
                rep.files
            );
        }
        if let Some((e, n)) = &rep.missing_example {
            eprintln!(
                "warning: {n} labelled images have no lane file here (e.g. {e}): `eval` \
                 refuses predictions that miss a labelled image; an image without lanes needs \
                 an empty lane file"
            );
        }
        for r in &mut records {
            if l.iter().any(|l| l.raw_file == r.raw_file) {
                r.run_time = Some(0.0);
            }
        }
    }
    let written: Vec<&tusimple::TuSimpleRecord> = records
        .iter()
        .filter(|r| labels.is_none() || r.run_time.is_some())
        .collect();
    tusimple::write_jsonl(out, &written)?;
    eprintln!(
        "{} images, {} lanes from {} to {}{}",
        rep.files,
        rep.lanes,
        dir.display(),
        out.display(),
        if labels.is_some() {
            " (the labelled images, at the labels' rows, as predictions for `eval`)"
        } else {
            ""
        }
    );
    let n_points: usize = rep.dropped.outside_points;
    if n_points > 0 || rep.dropped.lanes > 0 {
        eprintln!(
            "{n_points} lane points outside the {}x{} image of --camera left out, {} lanes \
             with fewer than two points or none inside it left out{}",
            cam.width,
            cam.height,
            rep.dropped.lanes,
            if rep.lanes == 0 || rep.dropped.lanes > rep.lanes {
                " (most of the lanes: is --camera the camera of these images?)"
            } else {
                ""
            }
        );
    }
    if let Some(f) = frames {
        let (fr, unnumbered) = culane::frames(&records, fps, &cam, labels.as_deref())?;
        tusimple::write_frames(f, &fr)?;
        eprintln!(
            "{} frames of lane points to {} ({}x{} camera, t = frame number / {fps} fps{}); \
             track them: stjpdacf track --frames {} --out pred.jsonl",
            fr.len(),
            f.display(),
            cam.width,
            cam.height,
            if unnumbered > 0 {
                format!(
                    "; {unnumbered} files without a frame number are 1 / {fps} s apart in \
                     name order"
                )
            } else {
                String::new()
            },
            f.display()
        );
    }
    Ok(())
}
