# Session 35's engine sweep on the device machine's 16 CPU cores (JAX on its CPU):
# the 40 variants simulated here by make_variants.py (into .devdata, carried), fitted and
# explained by bench_engine.py in 16 spawned workers (one XLA thread each).
export JAX_PLATFORMS=cpu PYTHONUNBUFFERED=1 PYTHONPATH=src
python3 -c "import jax, optimistix, equinox, numpy, scipy; print('jax', jax.__version__, 'optimistix', optimistix.__version__, 'equinox', equinox.__version__, 'numpy', numpy.__version__)"
nproc
ORDER="fps500 rub_fast250 rub_mu02 rub_stiffbend rub_links_h1 heavy20_250fps p14_n30_250fps fps200_v250 v100_cruise6 p10_w22_n40 mu02_heavy15 mu04_drawbar5 tau001 k015_heavy15 noisy3_h04 window300 window_late one_marker eight_tips h1_spread3 h07_three body_wide fps25 v400 cruise12 ramp02 p14_every2 p20_w30_n20 p30_w28_n14 k1_light3 tau05 lug10mm lug3mm knormal4 drawbar8_k03 crr02 crr003 mu_wheel05 tension25 tension150"
timeout -s INT ${SWEEP_S:-520} python3 benchmarks/bench_engine.py $ORDER --data .devdata --workers 16 --timeout 480 --log $OUT/device.jsonl 2>&1 | tee $OUT/device.txt
echo "sweep exit $?"
