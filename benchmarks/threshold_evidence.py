"""Evidence for the pair threshold (core/threshold.py, the pair threshold): on every shared pair (any .conf folder)
and the simulated scenes, where the truth and the nearest wrong minimum lie on the candidates' basis.

For each case: the pair's noise floor; at the true pose, the median matched d^2 over the floor and the
matched share; then ICP minima (core.global_search.refine: ICP on the cut at the start, then on the
cut at the pose found) from N seeded starts 20-120 degrees and up to 30 % of the size off; a minimum
more than the success bound off is wrong. Printed: the truth's ratio, the nearest wrong minimum's
(lowest ratio among those that overlap enough to pass), the leave-one-out factor (geometric mean of
the largest truth ratio and the smallest wrong ratio over the OTHER cases) and its spread, and per
case whether the threshold (with the factor left out for that case) lies between the two.

    python benchmarks/threshold_evidence.py [--starts 20] [--folder ../shared/data/bunny]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from app.sweep import shared_pairs  # noqa: E402
from core.candidates import CandidateConfig, make_basis  # noqa: E402
from core.global_search import refine  # noqa: E402
from core.icp import IcpConfig  # noqa: E402
from core.io import load_scan  # noqa: E402
from core.noise import noise_floor  # noqa: E402
from core.problem import ProblemConfig  # noqa: E402
from core.simulate import SCENES, make_scene, true_transform  # noqa: E402
from core.surface import Surface  # noqa: E402
from core.threshold import FACTOR, MIN_TRUST_OVERLAP  # noqa: E402
from core.transforms import apply, invert, perturb, pose_error, random_perturbation  # noqa: E402


def cases(folder: Path):
    for s_path, t_path, _ in shared_pairs(folder) if folder.is_dir() else []:
        s, t = load_scan(s_path), load_scan(t_path)
        yield f"{s_path.stem}->{t_path.stem}", s, t, invert(t.pose) @ s.pose, 2.0, 0.002
    for i, name in enumerate(SCENES):
        t, s = make_scene(name, i)
        yield name, s, t, true_transform(s, t), 1.0, 0.01 * t.size


def measure(name, s, t, T_true, ok_rot, ok_trans, starts: int) -> dict:
    surface = Surface.from_scan(t)
    rng = np.random.default_rng(0)
    floor = float(np.mean([noise_floor(x, rng, 300) for x in (s, t)]))
    basis = make_basis(s, t, surface, floor, rng, CandidateConfig())
    truth = basis.evaluate(T_true[None])
    rng = np.random.default_rng(7)
    c_t = apply(T_true, s.centroid[None])[0]
    wrong = []
    pc = ProblemConfig(rotation_uncertainty_deg=90.0, translation_uncertainty=0.3 * t.size)
    for _ in range(starts):
        tr, r = random_perturbation(rng, rng.uniform(20, 120), rng.uniform(0.0, 0.3) * t.size)
        T0 = perturb(T_true, np.r_[tr, r], c_t)
        try:
            T, _ = refine(s, t, surface, T0, pc, IcpConfig(metric=CandidateConfig().refine_metric))
        except Exception:  # noqa: BLE001 - a start with no overlap at all is no minimum
            continue
        rot, trans = pose_error(T, T_true, s.centroid)
        if rot >= ok_rot or trans >= ok_trans:
            sc = basis.evaluate(T[None])
            wrong.append((float(sc.inlier_median[0] / floor), float(sc.inliers[0]), float(sc.score[0] / basis.cap), rot,
                          trans))
    passing = [w for w in wrong if w[1] >= MIN_TRUST_OVERLAP]  # the others fail the test on overlap
    return {"case": name, "floor": floor, "truth_ratio": float(truth.inlier_median[0] / floor),
            "truth_share": float(truth.inliers[0]), "truth_score": float(truth.score[0] / basis.cap),
            "wrong": len(wrong), "nearest_wrong_ratio": min((w[0] for w in passing), default=np.inf),
            "nearest_wrong_pose": min(passing, default=(0, 0, 0, np.nan, np.nan))[3:],
            "wrong_share_max": max((w[1] for w in wrong), default=0.0),
            "lowest_wrong_score": min((w[2] for w in wrong), default=np.inf)}


AMBIGUOUS = {"wing": "E is flat along the panel by design (README): wrong minima match as well as the truth",
             "corner": "three planes: its twin turned 120 deg about the corner's diagonal fits at the noise level; "
                       "no test of one pose tells them apart (the fixed-basis score still ranks the truth first)"}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=20)
    ap.add_argument("--folder", default=str(ROOT.parent / "shared" / "data" / "bunny"))
    ap.add_argument("--cases", help="only these cases, comma-separated (e.g. corner,bowl)")
    a = ap.parse_args()
    rows = []
    for c in cases(Path(a.folder)):
        if a.cases and c[0] not in a.cases.split(","):
            continue
        rows.append(measure(*c, starts=a.starts))
        r = rows[-1]
        print(f"{r['case']:16s} floor {r['floor']:.3g}  truth: median/floor {r['truth_ratio']:.2f} share "
              f"{r['truth_share']:.2f} score/cap {r['truth_score']:.3f} | {r['wrong']} wrong minima: nearest "
              f"median/floor {r['nearest_wrong_ratio']:.2f} ({r['nearest_wrong_pose'][0]:.2f} deg, "
              f"{r['nearest_wrong_pose'][1]:.3g} off), largest share {r['wrong_share_max']:.2f}, lowest "
              f"score/cap {r['lowest_wrong_score']:.3f}", flush=True)
    fit = [r for r in rows if r["case"] not in AMBIGUOUS]
    for name, why in AMBIGUOUS.items():
        print(f"{name}: left out of the fit ({why})")
    hi, lo = max(r["truth_ratio"] for r in fit), min(r["nearest_wrong_ratio"] for r in fit)
    print(f"\nall cases: largest truth ratio {hi:.2f}, nearest wrong {lo:.2f}, geometric mean {np.sqrt(hi * lo):.2f} "
          f"(core.threshold.FACTOR = {FACTOR:g})")
    print("leave-one-out factor (geometric mean of the other cases' largest truth ratio and smallest wrong ratio):")
    factors = []
    for r in fit:
        others = [o for o in fit if o is not r]
        hi_truth = max(o["truth_ratio"] for o in others)
        lo_wrong = min(o["nearest_wrong_ratio"] for o in others)
        k = float(np.sqrt(hi_truth * lo_wrong))
        factors.append(k)
        holds = r["truth_ratio"] < FACTOR < r["nearest_wrong_ratio"]
        loo = r["truth_ratio"] < k < r["nearest_wrong_ratio"]
        print(f"  {r['case']:16s} truth {r['truth_ratio']:.2f} < {FACTOR:g} < nearest wrong {r['nearest_wrong_ratio']:.2f}: "
              f"{'holds' if holds else 'FAILS'}; with the factor fitted without it ({k:.2f}): "
              f"{'holds' if loo else 'FAILS'}; truth scores below every wrong "
              f"minimum: {r['truth_score'] < r['lowest_wrong_score']}")
    print(f"factor: spread {min(factors):.2f}-{max(factors):.2f} (inf: no wrong minimum passes the overlap test)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
