"""Headline slip z per kind: what the user is shown (explain's final), with the partial
family term's shift in quadrature as the final code does (explain._robust.partial_shift)."""
import json, sys, math
import numpy as np
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
kinds = []
for r in rows:
    if r["kind"] not in kinds: kinds.append(r["kind"])
print("| kind | n | headline slip z mean | rms | abs z <= 3 | unexplained with a partial term (shift carried) |")
print("|---|---|---|---|---|---|")
for k in kinds:
    zs, part = [], 0
    for r in rows:
        if r["kind"] != k or "error" in r: continue
        s, sd = r["slip_final"], r["std_final"]
        if r["verdict"] == "unexplained" and r["terms"] and r["chi2_after"] < r["chi2_final"] \
                and "free speed" not in str(r.get("method", "")):
            sd = math.hypot(sd, r["slip"] - s); part += 1
        zs.append((s - r["truth"]) / sd)
    z = np.array(zs)
    print(f"| {k} | {len(z)} | {z.mean():+.2f} | {np.sqrt(np.mean(z**2)):.2f} | {int(np.sum(abs(z)<=3))}/{len(z)} | {part} |")
