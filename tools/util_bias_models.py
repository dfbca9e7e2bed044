#!/usr/bin/env python3
"""Does a direction-dependent UWB TDOA bias model beat the position grid?

Leave-one-flight-out over the 23 UTIL TDOA flights (flights.csv): every
candidate bias model is learnt on 22 flights and scored on the held-out one.

Residuals. For every TDOA difference in the flight segment (motion-capture
height above 0.3 m), with (i, j) its anchors ordered lower id first and the
measurement's sign flipped where the log has them the other way round,
e = z - (|p_ant - a_j| - |p_ant - a_i|), p_ant the motion-capture position
interpolated at the measurement time plus the lever arm rotated by the
motion-capture attitude (as tools/util_tdoa_bound.py; the measured
distanceDiff is |p - a_idB| - |p - a_idA|). Residuals more than 0.3 m from
their pair's median in that flight are outliers, dropped everywhere (the
same measurement set for every candidate, so the fixes compare the models
and nothing else; at run time a filter would need its own gate).

Candidates (bias of the ordered pair (i, j), subtracted from z):
  none            0.
  pair_constant   each unordered pair's median residual.
  grid            per pair, the median per 1 m x-y cell of p_ant shrunk
                  towards the pair median by n/(n+20), cells with < 20
                  samples = the pair median, bilinear between cell centres
                  (crates/uwb/src/calibration.rs, Family::Grid defaults).
  dir Lk a=..     per anchor k a range bias b_k = c_k . phi(u_body, u_anc),
                  u_body the unit tag->anchor direction in the tag's body
                  frame (motion-capture attitude), u_anc the unit
                  anchor->tag direction in the anchor's frame (anN_quat of
                  anchors-const3.txt, x y z w: its +z axis is the anchor's
                  boresight, pointing into the room, for all 8 anchors);
                  phi = [1, real spherical harmonics of degree 1..L of
                  u_body, the same of u_anc]; the pair's TDOA bias is
                  b_j - b_i; c from ridge regression over all training
                  residuals, penalty alpha * N (N training residuals),
                  iteratively reweighted (Huber, 0.1 m,
                  3 passes from the weights after the training pair medians):
                  some flights carry per-anchor offsets of 0.4-0.6 m that
                  plain least squares spreads over everything ("LS dir":
                  the plain ridge fits, kept for comparison).
  dir-body / dir-anc   the same with one frame's harmonics only.
  dir+pair        joint (robust) ridge fit of the direction model and one constant
                  per unordered pair (constants barely penalised).
  grid+dir        the grid, then the direction model fitted to the training
                  residual left after the grid (in sample).

Metric 1: RMS per held-out flight of e - model(truth p_ant, truth attitude).
Metric 2: horizontal RMSE of a least-squares TDOA fix every 0.1 s over the
flight segment (Gauss-Newton of util_tdoa_bound.solve, started from the
previous fix; from the anchors' centroid at first and when a fix runs away:
non-finite, outside the anchors' box by more than 1 m, or an RMS residual
above 0.5 m; a fix that still fails holds the previous one), from the last
inlier of each pair in the 0.1 s before the epoch (at least 4 pairs), each
corrected by the model evaluated at the PREVIOUS fix and the TRUTH attitude
at the measurement time (a filter would use its own attitude estimate: the
direction model's score here is optimistic in that respect). Reported as
the ratio to the uncorrected fix (candidate none). A flight's RMSE can hang
on 2-3 epochs of poor geometry (4-5 pairs), so the ratio of the median
horizontal error is printed too.
Also printed: each flight's median yaw and its interquartile range
(motion capture, flight segment).

Usage: python3 tools/util_bias_models.py DATA_DIR
(numpy only, deterministic, single-threaded.)
"""
import csv
import os
import sys
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

sys.dont_write_bytecode = True  # leave no __pycache__ in tools/
sys.path.insert(0, str(Path(__file__).resolve().parent))
from util_tdoa_bound import LEVER, load, mocap_and_tdoa, rotate, solve  # noqa: E402

OUTLIER_M = 0.3
AIR_M = 0.3
CELL_M = 1.0
MIN_COUNT = 20
SHRINK = 20.0
LS = (1, 2, 3)
ALPHAS = (1e-3, 1e-2, 1e-1)  # ridge penalty = alpha * (training residuals)
HUBER_M = 0.1
ROBUST_ITERS = 3
ROBUST_SET = ((1, 1e-2), (2, 1e-2), (2, 1e-1), (3, 1e-2))
SHOW = ("cfBolt-log00", "test-log00", "flight-9268362f", "flight-4459574a")


def anchor_file(path):
    pos, quat = {}, {}
    for line in Path(path).read_text().splitlines():
        if not line.strip():
            continue
        k, *v = line.strip().split(",")
        v = np.array([float(x) for x in v])
        if k.endswith("_p"):
            pos[int(k[2:-2])] = v
        elif k.endswith("_quat"):
            quat[int(k[2:-5])] = v / np.linalg.norm(v)  # x y z w
    return pos, quat


def rotmat(q):
    """Body->world rotation matrices (n x 3 x 3) of quaternions x y z w."""
    return np.stack([rotate(q, np.broadcast_to(np.eye(3)[k], (len(q), 3))) for k in range(3)], -1)


def yaw_of(q):
    x, y, z, w = q.T
    return np.degrees(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def prep(data_dir, name, afile, quats):
    d = load(data_dir / name)
    apos, _ = anchor_file(data_dir / afile)
    tp, p, td, tt = mocap_and_tdoa(d)
    A, B = td[:, 1].astype(int), td[:, 2].astype(int)
    m = A != B
    td, tt, A, B = td[m], tt[m], A[m], B[m]
    air_t = tp[p[:, 3] > AIR_M]
    seg = (air_t[0], air_t[-1])
    i, j = np.minimum(A, B), np.maximum(A, B)
    z = np.where(A < B, 1.0, -1.0) * td[:, 3]  # |p - a_j| - |p - a_i|
    pos = np.stack([np.interp(tt, tp, p[:, 1 + k]) for k in range(3)], -1)
    q = np.stack([np.interp(tt, tp, p[:, 4 + k]) for k in range(4)], -1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = rotmat(q)
    ant = pos + np.einsum("nij,j->ni", R, LEVER)
    aid = np.array(sorted(apos))
    amat = np.array([apos[k] for k in aid])
    ai, aj = amat[i], amat[j]
    e = z - (np.linalg.norm(ant - aj, axis=1) - np.linalg.norm(ant - ai, axis=1))
    air = pos[:, 2] > AIR_M
    inl = np.zeros(len(e), bool)
    for key in set(zip(i[air], j[air])):
        s = air & (i == key[0]) & (j == key[1])
        med = np.median(e[s])
        inl[s] = np.abs(e[s] - med) <= OUTLIER_M
    # truth at a 0.1 s epoch grid for scoring the fixes
    ep = np.arange(seg[0] + 0.1, seg[1], 0.1)
    ptk = np.stack([np.interp(ep, tp, p[:, 1 + k]) for k in range(3)], -1)
    qtk = np.stack([np.interp(ep, tp, p[:, 4 + k]) for k in range(4)], -1)
    qtk /= np.linalg.norm(qtk, axis=1, keepdims=True)
    anttk = ptk + rotate(qtk, np.broadcast_to(LEVER, ptk.shape))
    segp = (tp >= seg[0]) & (tp <= seg[1])
    yaw = yaw_of(p[segp, 4:8])
    return dict(
        name=name, tt=tt, i=i, j=j, z=z, e=e, air=air, inl=inl, ant=ant, R=R,
        amat=amat, aquat=np.array([quats[k] for k in aid]),
        ep=ep, ep_air=ptk[:, 2] > AIR_M, ep_truth=anttk,
        yaw_med=float(np.degrees(np.angle(np.mean(np.exp(1j * np.radians(yaw)))))),
        yaw_iqr=float(np.subtract(*np.percentile(yaw, [75, 25]))),
        mode_pairs=len(set(zip(i[inl], j[inl]))),
    )


# ---------------------------------------------------------------- features
def sh(u, L):
    """Real spherical harmonics of degree 1..L (mean square 1 on the sphere)."""
    x, y, z = u[:, 0], u[:, 1], u[:, 2]
    out = [np.sqrt(3) * x, np.sqrt(3) * y, np.sqrt(3) * z]
    if L >= 2:
        s15 = np.sqrt(15)
        out += [s15 * x * y, s15 * y * z, np.sqrt(5) / 2 * (3 * z * z - 1), s15 * x * z,
                s15 / 2 * (x * x - y * y)]
    if L >= 3:
        out += [np.sqrt(35 / 8) * y * (3 * x * x - y * y), np.sqrt(105) * x * y * z,
                np.sqrt(21 / 8) * y * (5 * z * z - 1), np.sqrt(7) / 2 * z * (5 * z * z - 3),
                np.sqrt(21 / 8) * x * (5 * z * z - 1), np.sqrt(105) / 2 * z * (x * x - y * y),
                np.sqrt(35 / 8) * x * (x * x - 3 * y * y)]
    return np.stack(out, -1)


def nfeat(L, frames):
    return 1 + len(frames) * ((L + 1) ** 2 - 1)


def anchor_feats(p, R, k, amat, aR, L, frames):
    """phi of anchor k (per row) for antenna positions p, attitudes R."""
    d = amat[k] - p
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cols = [np.ones((len(p), 1))]
    if "body" in frames:
        cols.append(sh(np.einsum("nji,nj->ni", R, d), L))  # R^T d
    if "anc" in frames:
        cols.append(sh(np.einsum("nji,nj->ni", aR[k], -d), L))  # R_k^T (p - a_k)
    return np.concatenate(cols, 1)


def design(p, R, i, j, amat, aR, L, frames):
    """Rows: phi_j in block j, -phi_i in block i (8 anchors x F)."""
    F = nfeat(L, frames)
    n = len(p)
    A = np.zeros((n, len(amat) * F))
    fi = anchor_feats(p, R, i, amat, aR, L, frames)
    fj = anchor_feats(p, R, j, amat, aR, L, frames)
    cols = np.arange(F)
    rows = np.arange(n)[:, None]
    A[rows, i[:, None] * F + cols] -= fi
    A[rows, j[:, None] * F + cols] += fj
    return A


# ---------------------------------------------------------------- models
class PairConst:
    def __init__(self, fl):
        self.c = {}
        for key in sorted({k for f in fl for k in zip(f["i"][f["inl"]], f["j"][f["inl"]])}):
            v = np.concatenate([f["e"][f["inl"] & (f["i"] == key[0]) & (f["j"] == key[1])] for f in fl])
            if len(v) >= MIN_COUNT:
                self.c[key] = float(np.median(v))

    def __call__(self, f, idx, p, R):
        return np.array([self.c.get((a, b), 0.0) for a, b in zip(f["i"][idx], f["j"][idx])])


class Grid:
    def __init__(self, fl):
        self.pc = PairConst(fl)
        self.tabs = {}
        for key, c0 in self.pc.c.items():
            ps, es = [], []
            for f in fl:
                s = f["inl"] & (f["i"] == key[0]) & (f["j"] == key[1])
                ps.append(f["ant"][s, :2])
                es.append(f["e"][s])
            ps, es = np.concatenate(ps), np.concatenate(es)
            cx, cy = np.floor(ps[:, 0] / CELL_M).astype(int), np.floor(ps[:, 1] / CELL_M).astype(int)
            tab = {}
            for c in sorted(set(zip(cx, cy))):
                v = es[(cx == c[0]) & (cy == c[1])]
                if len(v) >= MIN_COUNT:
                    w = len(v) / (len(v) + SHRINK)
                    tab[c] = c0 + w * (float(np.median(v)) - c0)
            if not tab:
                self.tabs[key] = (np.full((1, 1), c0), 0, 0)
                continue
            ks = np.array(sorted(tab))
            ox, oy = ks[:, 0].min(), ks[:, 1].min()
            T = np.full((ks[:, 0].max() - ox + 1, ks[:, 1].max() - oy + 1), c0)
            for c, v in tab.items():
                T[c[0] - ox, c[1] - oy] = v
            self.tabs[key] = (T, ox, oy)

    def _look(self, key, ix, iy):
        T, ox, oy = self.tabs[key]
        a, b = ix - ox, iy - oy
        ok = (a >= 0) & (a < T.shape[0]) & (b >= 0) & (b < T.shape[1])
        out = np.full(len(ix), self.pc.c[key])
        out[ok] = T[a[ok], b[ok]]
        return out

    def __call__(self, f, idx, p, R):
        """Bilinear between cell centres ((k + 0.5) * CELL_M), as the product."""
        i, j = f["i"][idx], f["j"][idx]
        out = np.zeros(len(idx))
        u, v = p[:, 0] / CELL_M - 0.5, p[:, 1] / CELL_M - 0.5
        i0, j0 = np.floor(u).astype(int), np.floor(v).astype(int)
        fx, fy = np.clip(u - i0, 0, 1), np.clip(v - j0, 0, 1)
        for key in set(zip(i, j)):
            if key not in self.pc.c:
                continue
            s = (i == key[0]) & (j == key[1])
            a, b, x, y = i0[s], j0[s], fx[s], fy[s]
            out[s] = ((1 - x) * (1 - y) * self._look(key, a, b) + x * (1 - y) * self._look(key, a + 1, b)
                      + (1 - x) * y * self._look(key, a, b + 1) + x * y * self._look(key, a + 1, b + 1))
        return out


class Direction:
    def __init__(self, coef, L, frames, amat, aR, pairc=None, base=None):
        self.coef, self.L, self.frames, self.amat, self.aR = coef, L, frames, amat, aR
        self.pairc, self.base = pairc, base

    def __call__(self, f, idx, p, R):
        A = design(p, R, f["i"][idx], f["j"][idx], f["amat"], self.aR, self.L, self.frames)
        b = A @ self.coef
        if self.pairc is not None:
            b += np.array([self.pairc.get((a, c), 0.0) for a, c in zip(f["i"][idx], f["j"][idx])])
        if self.base is not None:
            b += self.base(f, idx, p, R)
        return b


class Zero:
    def __call__(self, f, idx, p, R):
        return np.zeros(len(idx))


# ---------------------------------------------------------------- scoring
def metric1(f, model):
    s = np.where(f["inl"])[0]
    r = f["e"][s] - model(f, s, f["ant"][s], f["R"][s])
    return float(np.sqrt(np.mean(r * r)))


def metric2(f, model):
    """Horizontal RMSE of the sequential LS fix, model at the previous fix."""
    tt, inl = f["tt"], f["inl"]
    amat = f["amat"]
    cen = amat.mean(0)
    lo, hi = amat.min(0) - 1.0, amat.max(0) + 1.0
    x = None
    sq, fails = [], 0
    starts = np.searchsorted(tt, f["ep"] - 0.1, side="right")
    ends = np.searchsorted(tt, f["ep"], side="right")
    for k in range(len(f["ep"])):
        last = {}
        for n in range(starts[k], ends[k]):
            if inl[n]:
                last[(f["i"][n], f["j"][n])] = n
        idx = np.array(sorted(last.values()), int)
        if len(idx) < 4:
            continue
        pa, pb, z = amat[f["i"][idx]], amat[f["j"][idx]], f["z"][idx]

        def fix(x0, zz):
            with np.errstate(all="ignore"):
                try:
                    y = solve(x0, pa, pb, zz)
                except np.linalg.LinAlgError:
                    return None
            if not np.all(np.isfinite(y)) or np.any(y < lo) or np.any(y > hi):
                return None
            r = zz - (np.linalg.norm(y - pb, axis=1) - np.linalg.norm(y - pa, axis=1))
            return y if np.sqrt(np.mean(r * r)) < 0.5 else None

        prev = x
        if prev is None:
            prev = fix(cen, z)  # bootstrap: the uncorrected fix from the centroid
            if prev is None:
                continue
        b = model(f, idx, np.broadcast_to(prev, (len(idx), 3)), f["R"][idx])
        y = fix(prev, z - b)
        if y is None:
            y = fix(cen, z - b)
        if y is None:
            fails += 1
            y = prev
        x = y
        if f["ep_air"][k]:
            sq.append(np.sum((x[:2] - f["ep_truth"][k, :2]) ** 2))
    return float(np.sqrt(np.mean(sq))), fails, float(np.sqrt(np.median(sq)))


# ---------------------------------------------------------------- fitting
class Blocks:
    """A flight's inlier design in blocks: per anchor pair (i, j) the rows'
    phi of anchor i and of anchor j (the row is phi_j in block j minus phi_i
    in block i, plus a one-hot pair column when pair constants are fitted)."""

    def __init__(self, f, L, frames, aR):
        s = np.where(f["inl"])[0]
        self.n = len(s)
        self.groups = []
        ii, jj = f["i"][s], f["j"][s]
        for key in sorted(set(zip(ii, jj))):
            r = np.where((ii == key[0]) & (jj == key[1]))[0]
            k = s[r]
            Pi = anchor_feats(f["ant"][k], f["R"][k], np.full(len(k), key[0]), f["amat"], aR, L, frames)
            Pj = anchor_feats(f["ant"][k], f["R"][k], np.full(len(k), key[1]), f["amat"], aR, L, frames)
            self.groups.append((key, r, Pi, Pj))
        self.F = nfeat(L, frames)

    def predict(self, c, npair, pair_idx):
        F = self.F
        out = np.zeros(self.n)
        for (i, j), r, Pi, Pj in self.groups:
            out[r] = Pj @ c[j * F:(j + 1) * F] - Pi @ c[i * F:(i + 1) * F]
            if npair:
                out[r] += c[8 * F + pair_idx[(i, j)]]
        return out

    def accumulate(self, G, g, y, w, npair, pair_idx):
        F = self.F
        for (i, j), r, Pi, Pj in self.groups:
            wr, yr = w[r], y[r]
            Wi, Wj = Pi * wr[:, None], Pj * wr[:, None]
            si, sj = slice(i * F, (i + 1) * F), slice(j * F, (j + 1) * F)
            G[si, si] += Wi.T @ Pi
            G[sj, sj] += Wj.T @ Pj
            x = Wi.T @ Pj
            G[si, sj] -= x
            G[sj, si] -= x.T
            g[sj] += Wj.T @ yr
            g[si] -= Wi.T @ yr
            if npair:
                q = 8 * F + pair_idx[(i, j)]
                G[q, q] += wr.sum()
                G[q, sj] += Wj.sum(0)
                G[q, si] -= Wi.sum(0)
                G[sj, q] += Wj.sum(0)
                G[si, q] -= Wi.sum(0)
                g[q] += wr @ yr


def huber_w(r):
    return np.minimum(1.0, HUBER_M / np.maximum(np.abs(r), 1e-12))


def fit(X, y, w0, pen, iters, npair, pair_idx):
    """Ridge least squares, then IRLS with Huber weights (iters > 1)."""
    w = list(w0)
    for it in range(iters):
        G = np.diag(pen).astype(float)
        g = np.zeros(len(pen))
        for x, v, ww in zip(X, y, w):
            x.accumulate(G, g, v, ww, npair, pair_idx)
        c = np.linalg.solve(G, g)
        if it + 1 < iters:
            w = [huber_w(v - x.predict(c, npair, pair_idx)) for x, v in zip(X, y)]
    return c


def main():
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    data_dir = Path(sys.argv[1])
    rows = list(csv.DictReader(open(data_dir / "flights.csv")))
    _, quats = anchor_file(data_dir / "anchors-const3.txt")
    fl = [prep(data_dir, r["file"], r["anchors"], quats) for r in rows]
    aR = rotmat(np.array([quats[k] for k in sorted(quats)]))
    names = [f["name"] for f in fl]
    nf = len(fl)
    allinl = np.concatenate([f["e"][f["inl"]] for f in fl])
    allair = np.concatenate([f["e"][f["air"]] for f in fl])
    print(f"{nf} flights, {len(allair)} residuals in the air, {len(allinl)} inliers "
          f"({100 * (1 - len(allinl) / len(allair)):.1f} % dropped); inlier median {np.median(allinl):+.3f} m, "
          f"RMS {np.sqrt(np.mean(allinl ** 2)):.3f} m", flush=True)

    print("\nyaw per flight (motion capture, flight segment): median deg, IQR deg")
    for f in fl:
        print(f"  {f['name']:18s} {f['yaw_med']:+7.1f} {f['yaw_iqr']:6.1f}")

    folds = [[g for g in range(nf) if g != h] for h in range(nf)]
    cands = {"none": [Zero()] * nf}
    cands["pair_constant"] = [PairConst([fl[g] for g in tr]) for tr in folds]
    cands["grid"] = [Grid([fl[g] for g in tr]) for tr in folds]
    ys = [f["e"][f["inl"]] for f in fl]
    # robust start of every fold's IRLS: Huber weights of the residual after
    # that fold's pair medians (no held-out data involved)
    w0 = []
    grid_tr = []  # grid prediction of each fold's grid on every flight's inliers
    for h in range(nf):
        pc, gr = cands["pair_constant"][h], cands["grid"][h]
        w0.append([huber_w(f["e"][f["inl"]] - pc(f, np.where(f["inl"])[0], None, None)) for f in fl])
        grid_tr.append([gr(f, np.where(f["inl"])[0], f["ant"][f["inl"]], None) for f in fl])
    ones = [np.ones(len(v)) for v in ys]
    print("\nfitted pair/grid models", flush=True)
    pair_keys = sorted({k for f in fl for k in zip(f["i"][f["inl"]], f["j"][f["inl"]])})
    pair_idx = {k: n for n, k in enumerate(pair_keys)}

    def run(label, L, frames, alpha, robust, with_pairs=False, on_grid=False):
        X = [Blocks(f, L, frames, aR) for f in fl]
        Fd = len(fl[0]["amat"]) * nfeat(L, frames)
        npair = len(pair_idx) if with_pairs else 0
        ms = []
        for h, tr in enumerate(folds):
            N = sum(len(ys[g]) for g in tr)
            pen = np.full(Fd + npair, alpha * N)
            pen[Fd:] = 1e-6 * N  # pair constants: barely penalised
            y = [ys[g] - grid_tr[h][g] if on_grid else ys[g] for g in tr]
            c = fit([X[g] for g in tr], y, [w0[h][g] for g in tr] if robust else [ones[g] for g in tr],
                    pen, ROBUST_ITERS if robust else 1, npair, pair_idx)
            pc = {k: float(c[Fd + n]) for k, n in pair_idx.items()} if with_pairs else None
            ms.append(Direction(c[:Fd], L, frames, None, aR, pairc=pc,
                                base=cands["grid"][h] if on_grid else None))
        cands[label] = ms
        print(f"fitted {label}", flush=True)

    both = ("body", "anc")
    # plain ridge least squares (no robust weights), the basis sizes and strengths
    for L in LS:
        for a in ALPHAS:
            run(f"LS dir L{L} a={a:g}", L, both, a, robust=False)
    # Huber-IRLS fits (the residuals are heavy-tailed: some flights carry
    # per-anchor offsets of 0.4-0.6 m that least squares spreads everywhere)
    for L, a in ROBUST_SET:
        run(f"dir L{L} a={a:g}", L, both, a, robust=True)
    m1 = {c: np.array([metric1(fl[h], cands[c][h]) for h in range(nf)]) for c in cands}
    rob = [f"dir L{L} a={a:g}" for L, a in ROBUST_SET]
    bestd = min(rob, key=lambda k: np.median(m1[k]))
    L, a = int(bestd.split("L")[1].split()[0]), float(bestd.split("a=")[1])
    run(f"dir-body L{L} a={a:g}", L, ("body",), a, robust=True)
    run(f"dir-anc L{L} a={a:g}", L, ("anc",), a, robust=True)
    run(f"dir+pair L{L} a={a:g}", L, both, a, robust=True, with_pairs=True)
    run(f"grid+dir L{L} a={a:g}", L, both, a, robust=True, on_grid=True)
    for c in cands:
        if c not in m1:
            m1[c] = np.array([metric1(fl[h], cands[c][h]) for h in range(nf)])

    print("\nmetric 1: RMS of the held-out residual after the model (m), over the flights")
    print(f"  {'candidate':28s} {'median':>7s} {'worst':>7s} {'mean':>7s}")
    for c in cands:
        print(f"  {c:28s} {np.median(m1[c]):7.4f} {m1[c].max():7.4f} {m1[c].mean():7.4f}")

    bestls = min((c for c in cands if c.startswith("LS ")), key=lambda k: np.median(m1[k]))
    m2set = ["none", "pair_constant", "grid", bestls] + rob + [c for c in cands if c.startswith(("dir-", "dir+", "grid+"))]
    m2, fails, p50 = {}, {}, {}
    for c in m2set:
        res = [metric2(fl[h], cands[c][h]) for h in range(nf)]
        m2[c] = np.array([r[0] for r in res])
        fails[c] = sum(r[1] for r in res)
        p50[c] = np.array([r[2] for r in res])
        print(f"metric 2 done: {c}", flush=True)
    base = m2["none"]
    print("\nmetric 2: horizontal RMSE of the sequential LS fix (m) and its ratio to none; metric 1 (m); fails: fixes\n"
          "  that held the previous one; p50 ratio: median over flights of the ratio of the median horizontal error\n"
          "  (a check that is blind to the few epochs of poor geometry that can dominate a flight's RMSE)")
    hdr = "".join(f" {n[:15]:>15s}" for n in SHOW)
    print(f"  {'candidate':28s} {'m2 med':>6s} {'ratio med':>9s} {'ratio worst':>11s} {'ratio best':>10s} "
          f"{'m1 med':>6s} {'m1 worst':>8s} {'fails':>5s} {'p50 ratio':>9s}{hdr}")
    for c in m2set:
        rt = m2[c] / base
        per = "".join(f" {rt[names.index(n)]:15.3f}" for n in SHOW if n in names)
        print(f"  {c:28s} {np.median(m2[c]):6.3f} {np.median(rt):9.3f} {rt.max():11.3f} {rt.min():10.3f} "
              f"{np.median(m1[c]):6.4f} {m1[c].max():8.4f} {fails[c]:5d} {np.median(p50[c] / p50['none']):9.3f}{per}")
    short = {c: c.replace(" a=", "/") for c in m2set}
    print("\nper flight: metric 2 of none (m), then the ratio to none per candidate")
    print(f"  {'flight':18s} {'none':>6s}" + "".join(f" {short[c][:14]:>14s}" for c in m2set[1:]))
    for h, n in enumerate(names):
        print(f"  {n:18s} {base[h]:6.3f}" + "".join(f" {m2[c][h] / base[h]:14.3f}" for c in m2set[1:]))
    wins = {c: int(np.sum(m2[c] < m2["grid"])) for c in m2set if c not in ("none", "grid")}
    print("\nflights where the candidate's fix beats the grid's: "
          + ", ".join(f"{c} {v}/{nf}" for c, v in wins.items()))
    print("\nper flight: metric 1 (m)")
    print(f"  {'flight':18s}" + "".join(f" {short[c][:14]:>14s}" for c in m2set))
    for h, n in enumerate(names):
        print(f"  {n:18s}" + "".join(f" {m1[c][h]:14.4f}" for c in m2set))


if __name__ == "__main__":
    main()
