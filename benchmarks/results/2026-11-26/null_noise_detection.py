# The detection statistics (explain._detect: Ljung-Box over 28 series x 20 lags, the
# cumulative periodogram with Bonferroni) of pure N(0,1) noise laid out as bench_scale's
# 100 000-frame recordings (12 lug + 2 body markers, drawn in simulate's order):
#   python null_noise_detection.py FIRST_SEED LAST_SEED  ->  seed, LB p, periodogram p
import numpy as np
from scipy import special
from fitlug.explain._detect import ljung_box, bartlett
def stats(seed, n=100000, nl=12, nb=2):
    rng = np.random.default_rng(seed)
    lx = rng.normal(0,1,n*nl); ly = rng.normal(0,1,n*nl); bx = rng.normal(0,1,n*nb); by = rng.normal(0,1,n*nb)
    q=0; best=1
    for a, k in ((lx,nl),(ly,nl),(bx,nb),(by,nb)):
        for m in range(k):
            x = a[m::k]; q += ljung_box(x,20); best = min(best, bartlett(x)[1])
    return special.chdtrc(560,q), min(1,best*28)
import sys
for s in range(int(sys.argv[1]), int(sys.argv[2])):
    print(s, *("%.4f" % v for v in stats(s)), flush=True)
