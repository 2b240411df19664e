"""Per case the engine slip, the reading before (earlier results) and after (this run), z and the std ratio:
    python compare.py AFTER.jsonl BEFORE.jsonl [MORE_BEFORE.jsonl ...]  (later files override)
"""
import json, sys, numpy as np
def load(f):
    d={}
    for l in open(f):
        r=json.loads(l); d[r["case"]]=r
    return d
A=load(sys.argv[1]); B={}
for f in sys.argv[2:]: B.update(load(f))
zs=[]; rel=[]
print(f"{'case':22s} {'engine':>7s} {'before':>18s} {'after':>18s} {'z0':>5s} {'z1':>5s} {'sig ratio':>9s}")
for c,r in sorted(A.items()):
    if r.get("slip") is None: print(c, "no slip", r.get("error","")[:80]); continue
    z1=(r["slip"]-r["engine_slip"])/r["std"]; zs.append(z1); rel.append(r["std"]/r["engine_slip"])
    b=B.get(c)
    if b and b.get("slip") is not None:
        z0=(b["slip"]-b["engine_slip"])/b["std"]; ratio=r["std"]/b["std"]
        bs=f"{b['slip']:.4f}+-{b['std']:.4f}"
    else: z0=float('nan'); ratio=float('nan'); bs="-"
    flag = " <<" if abs(ratio-1)>0.05 or abs(z1)>3 else ""
    print(f"{c:22s} {r['engine_slip']:7.4f} {bs:>18s} {r['slip']:.4f}+-{r['std']:.4f} {z0:5.1f} {z1:5.1f} {ratio:9.2f}{flag}")
zs=np.array(zs); print("n",len(zs),"within3",np.sum(abs(zs)<3),"mean",zs.mean().round(2),"rms",np.sqrt((zs**2).mean()).round(2),"sig/s median",np.median(rel).round(3))
