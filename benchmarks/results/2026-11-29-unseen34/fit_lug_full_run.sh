#!/bin/bash
d=$1; name=$(basename $d)
out=/tmp/s34/full/$name
s=$(date +%s.%N)
/usr/bin/time -f "%U %S" -o /tmp/s34/full/$name.time fit-lug $d/trajectories.csv --rig $d/rig.toml --out $out -q > /tmp/s34/full/$name.log 2>&1
rc=$?
e=$(date +%s.%N)
python3 - "$d" "$out" "$rc" "$s" "$e" "$name" <<'PY'
import json,sys
d,out,rc,s,e,name=sys.argv[1:]
t=json.load(open(d+'/truth.json'))['slip']
try:
    f=json.load(open(out+'/fit.json'))
    sl=f.get('slip') or {}
    v,sd=sl.get('value'),sl.get('std')
    ni=(f.get('not_identifiable') or {}).get('slip')
    cpu=sum(map(float,open(f'/tmp/s34/full/{name}.time').read().split()[-2:]))
    z=(v-t)/sd if v is not None and sd else None
    print(json.dumps(dict(case=name,truth=t,slip=v,std=sd,z=z,verdict=f['discrepancy']['verdict'],ni=ni,wall=float(e)-float(s),cpu=cpu,rc=int(rc))))
except Exception as ex:
    print(json.dumps(dict(case=name,truth=t,error=repr(ex)[:200],rc=int(rc))))
PY
