#!/usr/bin/env python3
"""gen3: an independent synthetic lane-detection generator (pure Python).

World: a road centre-line built from a curvature profile kappa(s) (arc length s,
0.5 m steps), markings are exact offset curves of it.  The car moves along the
road with speed v, lateral offset e(t) and heading psi(t) relative to the road
tangent.  Every world point is transformed into the car frame (u ahead, x right)
and projected with TuSimple's flat-road pinhole camera:
    col = 654 + 1000 x / u,   row = 238.5 + 1000 * (1.67 - h) / u   (h = height)
Detections: where a (painted) marking crosses a detector row, one point (centre
line) or two (both paint edges, --dense), column noise, per-row P_D, clutter.
Ground truth: the continuous marking centre lines at the h_samples rows on each
clip's last frame (TuSimple style: dashed markings labelled continuously).
"""
import argparse, bisect, json, math, os, random

W, H = 1280, 720
VP_COL, VP_ROW, F, CAM_H = 654.0, 238.5, 1000.0, 1.67
H_SAMPLES = list(range(160, 720, 10))
ROW_MIN = 250          # nearest-to-horizon row with detections / labels
DS = 0.5               # road polyline step (m)

PRESETS = {
    'clean':       dict(clutter=0, noise=0.0, pd=1.0, heading_jitter=0.0),
    'reference':   dict(),
    'clutter':     dict(clutter=180, blobs=6),
    'structures':  dict(structures=True),
    'curvy':       dict(curvy=True),
    'dense':       dict(dense=True),
    'fps10':       dict(fps=10, frames=10),
    'lanechange':  dict(lane_change=True),
}


def proj(u, x, h=0.0):
    return VP_COL + F * x / u, VP_ROW + F * (CAM_H - h) / u


class Road:
    """Centre line polyline; s index i -> s = s0 + i*DS."""

    def __init__(self, rng, s_len, kmax, curvy):
        self.s0 = -30.0
        n = int((s_len - self.s0) / DS) + 2
        ks = []
        if curvy:   # clothoid-ish: piecewise-linear kappa between knots 40-150 m apart
            knots = [(self.s0, rng.uniform(-kmax, kmax))]
            while knots[-1][0] < s_len:
                knots.append((knots[-1][0] + rng.uniform(40, 150), rng.uniform(-kmax, kmax)))
            j = 0
            for i in range(n):
                s = self.s0 + i * DS
                while knots[j + 1][0] < s:
                    j += 1
                (sa, ka), (sb, kb) = knots[j], knots[j + 1]
                ks.append(ka + (kb - ka) * (s - sa) / (sb - sa))
        else:       # gentle: constant + slow sinusoid, clamped
            k0 = rng.uniform(-kmax, kmax)
            a = rng.uniform(0, 0.5 * kmax)
            L = rng.uniform(300, 800)
            ph = rng.uniform(0, 2 * math.pi)
            for i in range(n):
                s = self.s0 + i * DS
                ks.append(max(-kmax, min(kmax, k0 + a * math.sin(2 * math.pi * s / L + ph))))
        self.X, self.Y, self.T = [0.0], [0.0], [0.0]
        for i in range(1, n):
            th = self.T[-1] + ks[i - 1] * DS
            tm = 0.5 * (th + self.T[-1])
            self.X.append(self.X[-1] + DS * math.cos(tm))
            self.Y.append(self.Y[-1] + DS * math.sin(tm))
            self.T.append(th)
        self.n = n

    def at(self, s, d=0.0):
        """World point at arc s, lateral offset d (right positive), and heading."""
        f = (s - self.s0) / DS
        i = max(0, min(self.n - 2, int(f)))
        a = f - i
        x = self.X[i] + a * (self.X[i + 1] - self.X[i])
        y = self.Y[i] + a * (self.Y[i + 1] - self.Y[i])
        th = self.T[i] + a * (self.T[i + 1] - self.T[i])
        return x + d * math.sin(th), y - d * math.cos(th), th


def to_car(pose, wx, wy):
    px, py, th = pose
    dx, dy = wx - px, wy - py
    c, s = math.cos(th), math.sin(th)
    return dx * c + dy * s, dx * s - dy * c     # u ahead, x right


def image_polyline(road, pose, d, s_from, s_to, step=DS):
    """Project the offset curve d over [s_from, s_to]: list of (row, col, s)."""
    out = []
    s = s_from
    while s <= s_to:
        wx, wy, _ = road.at(s, d)
        u, x = to_car(pose, wx, wy)
        if u > 1.0:
            c, r = proj(u, x)
            out.append((r, c, s))
        else:
            out.append(None)
        s += step
    return out


def crossings(poly, rows):
    """For each grid row, the first (nearest-to-car) crossing: dict row -> (col, s)."""
    res = {}
    rows_sorted = rows
    for a, b in zip(poly, poly[1:]):
        if a is None or b is None:
            continue
        ra, rb = a[0], b[0]
        lo, hi = (ra, rb) if ra <= rb else (rb, ra)
        if hi < rows_sorted[0] or lo > rows_sorted[-1] or hi == lo:
            continue
        k = bisect.bisect_left(rows_sorted, lo)
        while k < len(rows_sorted) and rows_sorted[k] <= hi:
            r = rows_sorted[k]
            if r not in res:
                w = (r - ra) / (rb - ra)
                res[r] = (a[1] + w * (b[1] - a[1]), a[2] + w * (b[2] - a[2]))
            k += 1
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--clips', type=int, default=40)
    ap.add_argument('--frames', type=int, default=None, help='frames per clip (default 20)')
    ap.add_argument('--fps', type=float, default=None, help='default 20')
    ap.add_argument('--cond', choices=sorted(PRESETS), default='reference', help='preset; knobs below override')
    ap.add_argument('--clutter', type=float, default=None, help='mean uniform clutter points / frame (30)')
    ap.add_argument('--blobs', type=float, default=None, help='mean clutter blobs (5-20 pts) / frame (0)')
    ap.add_argument('--noise', type=float, default=None, help='column noise sigma px (3)')
    ap.add_argument('--pd', type=float, default=None, help='per-row detection probability (0.85)')
    ap.add_argument('--heading-jitter', type=float, default=None, help='per-frame heading jitter rad (0.001)')
    ap.add_argument('--kmax', type=float, default=None, help='max |curvature| (1/1000, curvy 1/250)')
    ap.add_argument('--curvy', action='store_true', default=None)
    ap.add_argument('--structures', action='store_true', default=None)
    ap.add_argument('--dense', action='store_true', default=None)
    ap.add_argument('--lane-change', action='store_true', default=None)
    ap.add_argument('--out-dir', required=True)
    a = ap.parse_args()
    cfg = dict(frames=20, fps=20.0, clutter=30.0, blobs=0.0, noise=3.0, pd=0.85, heading_jitter=0.001,
               kmax=None, curvy=False, structures=False, dense=False, lane_change=False)
    cfg.update(PRESETS[a.cond])
    for k in list(cfg):
        v = getattr(a, k, None)
        if v is not None:
            cfg[k] = v
    if cfg['kmax'] is None:
        cfg['kmax'] = 1 / 250 if cfg['curvy'] else 1 / 1000
    rng = random.Random(a.seed * 7919 + sorted(PRESETS).index(a.cond))
    os.makedirs(a.out_dir, exist_ok=True)
    ff = open(os.path.join(a.out_dir, 'frames.jsonl'), 'w')
    fg = open(os.path.join(a.out_dir, 'gt.jsonl'), 'w')
    det_rows = list(range(ROW_MIN, 720, 1 if cfg['dense'] else 4))
    nF, fps = cfg['frames'], cfg['fps']
    dur = nF / fps
    npts = 0
    for ci in range(a.clips):
        clip = 'c%04d' % (ci + 1)
        nl = rng.randint(3, 5)
        w = rng.uniform(2.9, 3.9)
        v = rng.uniform(15, 35)
        marks = [(j - nl / 2) * w for j in range(nl + 1)]
        dashed = []
        for j in range(nl + 1):
            outer = j in (0, nl)
            dashed.append(rng.random() < (0.2 if outer else 0.75))
        phase = [rng.uniform(0, 12) for _ in marks]
        lane = rng.randrange(nl)
        lc_dir = 0
        if cfg['lane_change']:
            lc_dir = rng.choice([d for d in (-1, 1) if 0 <= lane + d < nl])
            lc_T = rng.uniform(1.8, 2.2)
            lc_mid = rng.uniform(0.2, 0.9) * dur      # marking crossing inside the clip
        c0 = (lane + 0.5 - nl / 2) * w
        wander_a, wander_T, wander_p = rng.uniform(0.05, 0.3), rng.uniform(3, 8), rng.uniform(0, 6.3)
        hd_a, hd_T, hd_p = rng.uniform(0, 0.004), rng.uniform(1, 3), rng.uniform(0, 6.3)
        s_start = rng.uniform(0, 50)
        road = Road(rng, s_start + v * dur + 320, cfg['kmax'], cfg['curvy'])

        def lat(t):
            e = c0 + wander_a * math.sin(2 * math.pi * t / wander_T + wander_p)
            if lc_dir:
                z = (t - (lc_mid - lc_T / 2)) / lc_T
                z = max(0.0, min(1.0, z))
                e += lc_dir * w * (0.5 - 0.5 * math.cos(math.pi * z))
            return e

        # structures: kerb / guard rail offsets, cars, seams
        side_lines, cars, seams = [], [], []
        if cfg['structures']:
            for side in (-1, 1):
                outer = marks[0] if side < 0 else marks[-1]
                side_lines.append(outer + side * rng.uniform(0.5, 1.5))      # kerb
                if rng.random() < 0.8:
                    side_lines.append(outer + side * rng.uniform(2.0, 4.0))  # guard rail
            for _ in range(rng.randint(2, 4)):
                li = rng.randrange(nl)
                du = rng.uniform(8, 70) if li != lane else rng.uniform(20, 70)
                cars.append(((li + 0.5 - nl / 2) * w + rng.uniform(-0.3, 0.3), s_start + du,
                             v + rng.uniform(-4, 4)))
            s = s_start + rng.uniform(5, 40)
            while s < s_start + v * dur + 200:
                seams.append((s, math.radians(rng.uniform(20, 70)) * rng.choice([-1, 1])))
                s += rng.uniform(30, 90)
        anchored_blobs = [(s_start + rng.uniform(5, 120), rng.uniform(marks[0] - 1, marks[-1] + 1))
                          for _ in range(int(cfg['blobs'] * 3))]

        for k in range(nF):
            t = k / fps
            sc = s_start + v * t
            e = lat(t)
            de = (lat(t + 1e-3) - lat(t - 1e-3)) / 2e-3
            psi = de / v + hd_a * math.sin(2 * math.pi * t / hd_T + hd_p) + rng.gauss(0, cfg['heading_jitter'])
            px, py, th = road.at(sc, e)
            pose = (px, py, th + psi)
            s_from, s_to = sc - 2, sc + 260
            pts = []

            def add(col, row, sig):
                col += rng.gauss(0, sig) if sig > 0 else 0.0
                if 0 <= col < W and ROW_MIN <= row < H:
                    pts.append([round(col, 2), row])

            # markings
            edge_cols = {}
            for j, d in enumerate(marks):
                offs = (d - 0.075, d + 0.075) if cfg['dense'] else (d,)
                for o in offs:
                    cr = crossings(image_polyline(road, pose, o, s_from, s_to), det_rows)
                    for r, (col, s) in cr.items():
                        if dashed[j] and (s + phase[j]) % 12.0 >= 3.0:
                            continue
                        if rng.random() < cfg['pd']:
                            add(col, r, cfg['noise'])
            # road span per row (outer markings +-1 m) for clutter
            span_rows = list(range(ROW_MIN, 720, 4))
            L = crossings(image_polyline(road, pose, marks[0] - 1, s_from, s_to, 1.0), span_rows)
            R = crossings(image_polyline(road, pose, marks[-1] + 1, s_from, s_to, 1.0), span_rows)

            def rand_road_pt():
                for _ in range(200):
                    r = rng.uniform(ROW_MIN, H - 1)
                    c = rng.uniform(0, W)
                    rr = min(span_rows, key=lambda q: abs(q - r))
                    lo = L.get(rr, (-1e9,))[0]
                    hi = R.get(rr, (1e9,))[0]
                    if lo <= c <= hi:
                        return c, int(round(r))
                return None

            n_cl = poisson(rng, cfg['clutter'])
            for _ in range(n_cl):
                p = rand_road_pt()
                if p:
                    add(p[0], p[1], 0)
            if cfg['blobs'] > 0:
                centres = []
                for _ in range(poisson(rng, cfg['blobs'] / 2)):
                    p = rand_road_pt()
                    if p:
                        centres.append(p)
                for (bs, bd) in anchored_blobs:      # road stains moving with the ground
                    wx, wy, _ = road.at(bs, bd)
                    u, x = to_car(pose, wx, wy)
                    if u > 3:
                        c, r = proj(u, x)
                        if ROW_MIN <= r < H and 0 <= c < W and rng.random() < 0.5:
                            centres.append((c, r))
                for (c, r) in centres:
                    sz = rng.uniform(4, 15)
                    for _ in range(rng.randint(5, 20)):
                        add(c + rng.gauss(0, sz), int(round(r + rng.gauss(0, sz * 0.6))), 0)
            if cfg['structures']:
                for o in side_lines:
                    cr = crossings(image_polyline(road, pose, o, s_from, s_to), det_rows)
                    for r, (col, s) in cr.items():
                        if rng.random() < 0.7:
                            add(col, r, cfg['noise'])
                for (cd, cs, cv) in cars:
                    s_veh = cs + cv * t
                    for side in (-1, 1):                      # rear corners: vertical edges
                        wx, wy, _ = road.at(s_veh, cd + side * 0.9)
                        u, x = to_car(pose, wx, wy)
                        if u < 4:
                            continue
                        col = VP_COL + F * x / u
                        r0, r1 = VP_ROW + F * (CAM_H - 1.4) / u, VP_ROW + F * (CAM_H - 0.3) / u
                        for r in det_rows:
                            if r0 <= r <= r1 and rng.random() < 0.8:
                                add(col, r, cfg['noise'])
                    side = -1 if cd > e else 1                # side edge facing the ego car
                    if abs(cd - e) > w / 2:
                        poly = []
                        for q in range(11):
                            wx, wy, _ = road.at(s_veh + 0.45 * q, cd + side * 0.9)
                            u, x = to_car(pose, wx, wy)
                            if u > 1:
                                c, r = proj(u, x, 0.35)
                                poly.append((r, c, 0))
                        for r, (col, _) in crossings(poly, det_rows).items():
                            if rng.random() < 0.8:
                                add(col, r, cfg['noise'])
                for (ss, ang) in seams:                       # straight tar seams across the road
                    wx0, wy0, th0 = road.at(ss, 0.0)
                    dx, dy = math.cos(th0 - ang), math.sin(th0 - ang)
                    half = (marks[-1] - marks[0] + 2) / 2 / abs(math.sin(ang))
                    poly = []
                    lam = -half
                    while lam <= half:
                        u, x = to_car(pose, wx0 + lam * dx, wy0 + lam * dy)
                        if u > 1:
                            c, r = proj(u, x)
                            poly.append((r, c, 0))
                        else:
                            poly.append(None)
                        lam += 0.25
                    for r, (col, _) in crossings(poly, det_rows).items():
                        if rng.random() < 0.8:
                            add(col, r, cfg['noise'])
            pts.sort(key=lambda p: (p[1], p[0]))
            npts += len(pts)
            fr = {'clip': clip, 't': round(t, 6), 'points': pts}
            if k == nF - 1:
                raw = 'gen3/%s/%d.jpg' % (clip, nF)
                fr['raw_file'] = raw
                fr['h_samples'] = H_SAMPLES
                lanes = []
                order = sorted(range(len(marks)), key=lambda j: abs(marks[j] - e))[:5]
                for j in sorted(order, key=lambda j: marks[j]):
                    cr = crossings(image_polyline(road, pose, marks[j], s_from, s_to, 0.25), H_SAMPLES)
                    lane_cols = []
                    for r in H_SAMPLES:
                        if r >= ROW_MIN and r in cr and 0 <= cr[r][0] < W:
                            lane_cols.append(round(cr[r][0], 1))
                        else:
                            lane_cols.append(-2)
                    if sum(1 for c in lane_cols if c >= 0) >= 5:
                        lanes.append(lane_cols)
                fg.write(json.dumps({'raw_file': raw, 'h_samples': H_SAMPLES, 'lanes': lanes}) + '\n')
            ff.write(json.dumps(fr, separators=(',', ':')) + '\n')
    ff.close(); fg.close()
    print(json.dumps({'cond': a.cond, 'seed': a.seed, 'clips': a.clips, 'frames': nF, 'fps': fps,
                      'mean_points_per_frame': round(npts / (a.clips * nF), 1)}))


def poisson(rng, lam):
    if lam <= 0:
        return 0
    if lam > 50:
        return max(0, int(round(rng.gauss(lam, math.sqrt(lam)))))
    L, k, p = math.exp(-lam), 0, 1.0
    while True:
        p *= rng.random()
        if p <= L:
            return k
        k += 1


if __name__ == '__main__':
    main()
