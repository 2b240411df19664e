import json, sys, statistics, collections
rows = collections.defaultdict(list)
for line in open(sys.argv[1]):
    parts = line.split(" ", 3)
    if len(parts) < 4 or "{" not in parts[3]: continue
    v, kind, load = parts[0], parts[1], parts[2]
    js = parts[3][parts[3].index("{"):parts[3].rindex("}") + 1]
    d = json.loads(js)
    t = parts[3][parts[3].index("TIME"):].split()
    wall, cpu = float(t[1]), float(t[2]) + float(t[3])
    rows[(v, kind)].append(dict(wall=wall, cpu=cpu, load=load, split=d["split"], slip=d["slip"], steps=d["steps"], verdict=d["verdict"]))
ST = ("startup", "reading", "fitting", "explaining", "sampling", "report")
for (v, kind), rs in rows.items():
    print(v, kind, "n", len(rs), "loads", [r["load"] for r in rs])
    print("   wall", [r["wall"] for r in rs], "cpu", [round(r["cpu"], 2) for r in rs])
    med = lambda xs: statistics.median(xs)
    print(f"   median wall {med([r['wall'] for r in rs]):.1f} cpu {med([r['cpu'] for r in rs]):.2f}")
    print("   stage cpu medians", " ".join(f"{s} {med([r['split'][s]['cpu'] for r in rs]):.2f}" for s in ST),
          "| rest", round(med([r['cpu'] - sum(r['split'][s]['cpu'] for s in ST) for r in rs]), 2))
    print("   stage wall medians", " ".join(f"{s} {med([r['split'][s]['wall'] for r in rs]):.2f}" for s in ST))
    print("   slip", {r["slip"] for r in rs}, {r["steps"] for r in rs}, {r["verdict"] for r in rs})
