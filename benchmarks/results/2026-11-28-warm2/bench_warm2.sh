#!/bin/bash
# interleaved warm runs of three versions of fitlug's src; one line of JSON per run
cd /work/wt-warm
CSV=data/reference/trajectories.csv
one() {  # version src cache kind
  local v=$1 src=$2 cache=$3 kind=$4 out=/tmp/warm2/bout_$1
  rm -rf $out
  local line
  line=$(FITLUG_CACHE_DIR=$cache PYTHONPATH=$src /usr/bin/time -f "TIME %e %U %S" python3 /tmp/warm2/bench_speed.py --worker $CSV $out 2>&1 | grep -E '^\{|^TIME')
  echo "$v $kind $(uptime | sed 's/.*average: //; s/,.*//') $(echo "$line" | tr '\n' ' ')"
}
for v in before merge after; do one $v /tmp/warm2/${v}_src /tmp/warm2/cache prime; done
for i in 1 2 3; do for v in before merge after; do one $v /tmp/warm2/${v}_src /tmp/warm2/cache warm; done; done
for v in before after; do rm -rf /tmp/warm2/cache_fresh_$v; one $v /tmp/warm2/${v}_src /tmp/warm2/cache_fresh_$v first; done
