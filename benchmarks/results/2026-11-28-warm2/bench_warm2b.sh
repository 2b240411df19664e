#!/bin/bash
cd /work/wt-warm
CSV=data/reference/trajectories.csv
one() {
  local v=$1 src=$2 cache=$3 kind=$4 out=/tmp/warm2/bout_$1
  rm -rf $out
  local line
  line=$(FITLUG_CACHE_DIR=$cache PYTHONPATH=$src /usr/bin/time -f "TIME %e %U %S" python3 /tmp/warm2/bench_speed.py --worker $CSV $out 2>&1 | grep -E '^\{|^TIME')
  echo "$v $kind $(uptime | sed 's/.*average: //; s/,.*//') $(echo "$line" | tr '\n' ' ')"
}
one after3 /tmp/warm2/after3_src /tmp/warm2/cache prime
for i in 1 2 3; do for v in before merge after3; do one $v /tmp/warm2/${v}_src /tmp/warm2/cache warm; done; done
rm -rf /tmp/warm2/cache_fresh_after3; one after3 /tmp/warm2/after3_src /tmp/warm2/cache_fresh_after3 first
