import json, sys, numpy as np
rows=[json.loads(l) for l in open(sys.argv[1])]
print(f"{'case':16s} {'err':>8s} {'std':>7s} {'z':>5s} {'f':>5s} {'dv%':>6s} | z corr a=.5 (+.5 term) | z term a=1 | z term a=.5")
Z={k:[] for k in ('cur','c5','t1','t5')}
for d in sorted(rows,key=lambda d:d['case']):
    if d.get('straight_method')!='belt clock' or d.get('v_body_window') is None: 
        print(d['case'], d.get('straight_method')); continue
    s=d['slip']; e=s-d['engine_slip']; sd=d['std']
    (ta,tb),(t1,t2)=d['window_s'],d['cruise_s']
    f=1-(tb-ta)/(t2-t1)
    vc,vw=d['v_body'],d['v_body_window']
    vo=(vc*(t2-t1)-vw*(tb-ta))/max((t2-t1)-(tb-ta),1e-9) if f>1e-6 else vw
    D=(vo-vw)/vw
    term=lambda a:(1-s)*f*a*abs(D)
    corr=(1-s)*f*0.5*D
    zc=(e+corr)/np.hypot(sd,term(0.5)); z1=e/np.hypot(sd,term(1)); z5=e/np.hypot(sd,term(0.5))
    Z['cur'].append(e/sd); Z['c5'].append(zc); Z['t1'].append(z1); Z['t5'].append(z5)
    print(f"{d['case']:16s} {e:8.4f} {sd:7.4f} {e/sd:5.1f} {f:5.2f} {100*D:6.2f} | {zc:5.1f} sd {np.hypot(sd,term(.5)):.4f} | {z1:5.1f} sd {np.hypot(sd,term(1)):.4f} | {z5:5.1f}")
for k,v in Z.items(): v=np.array(v); print(k, f"mean {v.mean():.2f} rms {np.sqrt(np.mean(v**2)):.2f} max|z| {np.abs(v).max():.2f} n>3 {np.sum(np.abs(v)>3)}")
