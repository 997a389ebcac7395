"""baarda from Python: analyse the bundled demo block, look at its worst tests as a DataFrame,
test a hypothesis, re-test under another policy and re-analyse without a suspect.

Run from the repository root:  .venv/bin/python examples/quickstart.py
"""

from pathlib import Path

import baarda

ROOT = Path(__file__).resolve().parents[1]

analysis = baarda.analyze(ROOT / "data" / "demo-block.json")
print(analysis)                                      # one line: sizes, global test, rejections

s = analysis.summary()
print(f"σ̂0 = {s['sigma0_aposteriori']:.3f}, global test {'passed' if s['global_test']['passed'] else 'failed'}")

obs = analysis.records("observations", frame=True)  # the JSON's observation table as a DataFrame
obs["abs_w"] = obs["w"].abs()
print(obs.nlargest(5, "abs_w")[["index", "kind", "image", "point", "w", "redundancy", "mdb", "rejected"]])

# a point-transfer error of the worst point in the images that measure it (F80 eq. 10-12)
worst = obs.loc[obs["abs_w"].idxmax()]
t = analysis.test(f"control:{worst['point']}") if worst["kind"] == "control" else \
    analysis.test(f"image-point:{worst['image']}:{worst['point']}")
print(f"{t['label']}: T = {t['T']:.1f} (q = {t['dimension']}, critical {t['critical_T']:.2f})")

# the same adjustment under a larger α0: nothing adjusted again
relaxed = analysis.with_policy(baarda.TestPolicy(alpha0=0.01))
print(f"rejected at α0 = 0.001: {analysis.summary()['n_rejected']}, at 0.01: {relaxed.summary()['n_rejected']}")

# without the worst observation: adjusted again
cleaner = analysis.without([int(worst["index"])])
print(f"without #{int(worst['index'])}: σ̂0 = {cleaner.summary()['sigma0_aposteriori']:.3f}")

# the errors planted in the demo block, and whether the tests found them
for found in analysis.planted(ROOT / "data" / "demo-block.truth.json"):
    print(found["kind"], found["ids"], "FOUND" if found["found"] else "missed")
