/* Host C example of the stjpdacf C API: the lane tracker over a points file, writing TuSimple
 * predictions (JSON lines) that must equal `stjpdacf track`'s lane for lane (only run_time
 * differs). CI builds it against the host staticlib and compares (`cargo xtask capi`).
 *
 *   stjpdacf track --frames F.jsonl --out rust.json --export-points points.txt
 *   cc -std=c11 -O2 -ffp-contract=off -Icapi/include capi/examples/track.c \
 *      target/release/libstjpdacf_capi.a -lm -lpthread -ldl -o track_c
 *   ./track_c points.txt c.json
 *
 * The points file (see `stjpdacf_tools::track::write_points_header`) holds each frame's BEV
 * points *after* the tools' preprocessing (image → BEV through the camera, row binning,
 * clustering: host-side work a front end does before the MCU) and the image rows at which a
 * prediction is due. This program does what an integrator's C code does: one tracker in a
 * caller-owned buffer, `stjpdacf_init` per clip, `stjpdacf_step` per frame, and the lanes
 * evaluated back into the image with `stjpdacf_lane_at` (the rules of `track::lane_x`).
 *
 * With -DSTJPDACF_EXAMPLE_RANK5 it runs the rank-5 model (stjpdacf_rank5_*), with
 * -DSTJPDACF_EXAMPLE_SMALL the small one (stjpdacf_small_*): compare with `stjpdacf track
 * --model rank5` / `--model small` (CI does all three). */
#define _POSIX_C_SOURCE 199309L /* clock_gettime */
#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "stjpdacf.h"

#if defined(STJPDACF_EXAMPLE_SMALL)
#define TRACKER stjpdacf_small_tracker
#define TRACKER_SIZE STJPDACF_SMALL_TRACKER_SIZE
#define TRACKER_INIT stjpdacf_small_init
#define TRACKER_STEP stjpdacf_small_step
#define TRACKER_LANE_AT stjpdacf_small_lane_at
#elif defined(STJPDACF_EXAMPLE_RANK5)
#define TRACKER stjpdacf_rank5_tracker
#define TRACKER_SIZE STJPDACF_RANK5_TRACKER_SIZE
#define TRACKER_INIT stjpdacf_rank5_init
#define TRACKER_STEP stjpdacf_rank5_step
#define TRACKER_LANE_AT stjpdacf_rank5_lane_at
#else
#define TRACKER stjpdacf_tracker
#define TRACKER_SIZE STJPDACF_TRACKER_SIZE
#define TRACKER_INIT stjpdacf_init
#define TRACKER_STEP stjpdacf_step
#define TRACKER_LANE_AT stjpdacf_lane_at
#endif

/* Lanes not seen for more frames than this are not written (`track::MAX_REPORT_MISSES`). */
#define MAX_REPORT_MISSES 2u
#define NO_POINT (-2.0)

/* The tracker's memory: caller-owned, no allocation inside the library. */
static _Alignas(STJPDACF_TRACKER_ALIGN) unsigned char memory[TRACKER_SIZE];

typedef struct {
    double width, height, vp_col, vp_row, height_m, focal_px;
} camera;

typedef struct {
    double key; /* lateral position at the nearest index point, the sort key */
    double *cols;
} out_lane;

static stjpdacf_model model;

static void die(const char *what) {
    fprintf(stderr, "track_c: %s\n", what);
    exit(1);
}

static double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

/* Image row → metres ahead (`Camera::to_bev` at the principal column); 0 when none. */
static int row_to_u(const camera *c, double row, double *u) {
    double dr = row - c->vp_row;
    if (!(isfinite(dr) && dr > 0.0)) return 0;
    double scale = c->height_m / dr;
    *u = c->focal_px * scale;
    return 1;
}

/* Where lane `l` is at `u` metres ahead (`track::lane_x`): the tracker's GP inside the window,
 * the line through the two nearest index points nearer than it, nothing beyond the window's far
 * end (no evidence there) or outside the observed extent (one index interval of margin). */
static int lane_x(TRACKER *t, const stjpdacf_lane *l, double u, double *x) {
    double u_min = model.u_min, u_max = model.u_max;
    double interval = (u_max - u_min) / 15.0;
    double first = l->u_first, last = l->u_last;
    /* Rust's (last + interval).min(u_max): u_max when the sum is NaN. */
    double end = last + interval < u_max ? last + interval : u_max;
    int reported = isfinite(u) && u >= first - interval && u <= end;
    if (!reported) return 0;
    if (u >= u_min && u <= u_max) {
        float xf;
        if (TRACKER_LANE_AT(t, l->slot, (float)u, &xf, NULL) != STJPDACF_OK) return 0;
        *x = xf;
        return 1;
    }
    /* Nearer than the window: the line through index points 0 and 1. */
    double u0 = model.index_u[0], u1 = model.index_u[1];
    double x0 = l->z[0], x1 = l->z[1];
    *x = x0 + (u - u0) * (x0 - x1) / (u0 - u1);
    return 1;
}

/* Rust's f64::total_cmp as an integer key. */
static int64_t total_key(double v) {
    int64_t k;
    memcpy(&k, &v, sizeof k);
    return k ^ (int64_t)((uint64_t)(k >> 63) >> 1);
}

static void print_num(FILE *f, double v) { fprintf(f, "%.17g", v); }

int main(int argc, char **argv) {
    if (argc != 3) die("usage: track_c POINTS.txt OUT.json");
    FILE *in = fopen(argv[1], "r");
    FILE *out = fopen(argv[2], "w");
    if (!in || !out) die("cannot open the input or the output");
    int version = 0;
    camera cam;
    if (fscanf(in, " stjpdacf-points %d", &version) != 1 || version != 1) die("not a points file");
    if (fscanf(in, " camera %lf %lf %lf %lf %lf %lf", &cam.width, &cam.height, &cam.vp_col,
               &cam.vp_row, &cam.height_m, &cam.focal_px) != 6)
        die("bad camera line");
    if (stjpdacf_model_info(&model) != STJPDACF_OK) die("stjpdacf_model_info");

    TRACKER *t = NULL;
    long clip = -1, next_clip;
    int64_t time_us;
    size_t n_points, n_rows, cap_points = 0, cap_rows = 0;
    char raw_file[4096];
    float *points = NULL;
    double *rows = NULL, *row_u = NULL;
    int *row_ok = NULL;
    unsigned frames = 0, predictions = 0, rejected = 0;
    stjpdacf_lane lanes[STJPDACF_MAX_LANES];
    out_lane outl[STJPDACF_MAX_LANES] = {{0}};
    unsigned clips = 0;
    while (fscanf(in, " frame %ld %" SCNd64 " %zu %zu %4095s", &next_clip, &time_us, &n_points,
                  &n_rows, raw_file) == 5) {
        if (n_points > cap_points) {
            cap_points = n_points;
            points = realloc(points, 2 * cap_points * sizeof *points);
        }
        if (n_rows > cap_rows) {
            cap_rows = n_rows;
            rows = realloc(rows, cap_rows * sizeof *rows);
            row_u = realloc(row_u, cap_rows * sizeof *row_u);
            row_ok = realloc(row_ok, cap_rows * sizeof *row_ok);
            for (size_t k = 0; k < STJPDACF_MAX_LANES; k++) {
                outl[k].cols = realloc(outl[k].cols, cap_rows * sizeof(double));
                if (!outl[k].cols) die("out of memory");
            }
        }
        if ((n_points && !points) || (n_rows && !(rows && row_u && row_ok))) die("out of memory");
        for (size_t k = 0; k < n_points; k++)
            if (fscanf(in, "%f %f", &points[2 * k], &points[2 * k + 1]) != 2) die("bad point");
        for (size_t k = 0; k < n_rows; k++)
            if (fscanf(in, "%lf", &rows[k]) != 1) die("bad row");
        if (next_clip != clip) { /* a new clip: a fresh tracker in the same memory */
            if (TRACKER_INIT(memory, sizeof memory, &t) != STJPDACF_OK) die("stjpdacf_init");
            clip = next_clip;
            clips++;
        }
        frames++;
        double start = now_ms();
        stjpdacf_report rep;
        stjpdacf_status st =
            TRACKER_STEP(t, time_us, points, n_points, lanes, STJPDACF_MAX_LANES, &rep);
        if (st == STJPDACF_NON_INCREASING_TIME) {
            rejected++;
            continue;
        }
        if (st < 0) die("stjpdacf_step refused a frame");
        if (n_rows == 0) continue;
        /* The lanes at the rows, in the image; those with a point, left to right. */
        size_t n_out = 0;
        for (size_t k = 0; k < n_rows; k++) row_ok[k] = row_to_u(&cam, rows[k], &row_u[k]);
        for (uint32_t li = 0; li < rep.filtered_lanes; li++) {
            const stjpdacf_lane *l = &lanes[li];
            if (l->misses > MAX_REPORT_MISSES) continue;
            out_lane *o = &outl[n_out];
            int any = 0;
            for (size_t k = 0; k < n_rows; k++) {
                double u = row_u[k], x, col = NO_POINT;
                if (row_ok[k] && lane_x(t, l, u, &x) && isfinite(u) && u > 0.0 && isfinite(x)) {
                    double c = cam.vp_col + cam.focal_px * x / u;
                    if (c >= 0.0 && c < cam.width) col = c;
                }
                o->cols[k] = col;
                any |= col >= 0.0;
            }
            if (!any) continue;
            o->key = l->z[0];
            /* Stable insertion by the total order of the key (Rust's sort_by total_cmp). */
            for (size_t m = n_out; m > 0 && total_key(outl[m - 1].key) > total_key(outl[m].key);
                 m--) {
                out_lane tmp = outl[m - 1];
                outl[m - 1] = outl[m];
                outl[m] = tmp;
            }
            n_out++;
        }
        double run_ms = now_ms() - start;
        fprintf(out, "{\"raw_file\":\"%s\",\"lanes\":[", raw_file);
        for (size_t m = 0; m < n_out; m++) {
            fputs(m ? ",[" : "[", out);
            for (size_t k = 0; k < n_rows; k++) {
                if (k) fputc(',', out);
                print_num(out, outl[m].cols[k]);
            }
            fputc(']', out);
        }
        fputs("],\"h_samples\":[", out);
        for (size_t k = 0; k < n_rows; k++) {
            if (k) fputc(',', out);
            print_num(out, rows[k]);
        }
        fprintf(out, "],\"run_time\":%.6f}\n", run_ms);
        predictions++;
    }
    if (!feof(in)) die("malformed points file");
    fclose(out);
    fprintf(stderr, "track_c: %u frames in %u clips, %u predictions, %u steps rejected\n", frames,
            clips, predictions, rejected);
    return 0;
}
