#!/usr/bin/env bash
# The first start with a cold and a warm kernel cache (issue 33 item 5): time to a ready
# page of `serve` (GET / answers 200) and a whole `run collision`, each with the kernel
# cache of TREE deleted, then after `python -m app.runs.warm`, twice.
#
#   git clone . /tmp/fresh && ln -s "$PWD/.venv" /tmp/fresh/.venv
#   bash benchmarks/first_start.sh /tmp/fresh 8731 /tmp/first-start
#
# It DELETES the numba cache of TREE (app/sim/__pycache__/*.nbi, *.nbc): give it a clone.
# A run's forecast cache is OUT/cache (emptied before the cold run and the warm-up: a first
# run of the setting after an install).
set -u
T=$1; PORT=$2; OUT=${3:-/tmp/first-start}
mkdir -p "$OUT"
export PYTHONPATH=$T ORBIT_EMULATOR_CACHE=$OUT/cache
cd "$T"
PY=$T/.venv/bin/python
now() { date +%s.%N; }
SERVE_PID=""  # the serve under way, ended however the script ends (a closed pipe too)
end_serve() { [[ -n "$SERVE_PID" ]] && kill "$SERVE_PID" 2>/dev/null; SERVE_PID=""; }
trap 'end_serve' EXIT
trap 'end_serve; exit 130' INT TERM HUP PIPE
serve_ready() {
  local t0; t0=$(now)
  $PY -m app.cli serve --port "$PORT" --runs-dir "$OUT/web" >"$OUT/serve.log" 2>&1 &
  local pid=$!
  SERVE_PID=$pid
  until curl -sf -o /dev/null "http://127.0.0.1:$PORT/"; do
    sleep 0.2
    kill -0 $pid 2>/dev/null || { echo "serve died (see $OUT/serve.log)"; break; }
  done
  echo "serve ready $(echo "$(now) - $t0" | bc) s"
  end_serve; wait $pid 2>/dev/null
}
run_collision() {  # with "fresh": no kept forecast or pre-flight reference
  [[ "${1:-}" == fresh ]] && rm -rf "$OUT/cache"
  local t0; t0=$(now)
  $PY -m app.cli run collision --quiet --out "$OUT/run" >/dev/null 2>&1 || echo "run failed"
  echo "run collision $(echo "$(now) - $t0" | bc) s"
}
cold() { rm -f app/sim/__pycache__/*.nbi app/sim/__pycache__/*.nbc \
           app/sim/__pycache__/orbit-emulator-warm.json; }
uptime
echo "== cold kernel cache"
cold; serve_ready
cold; run_collision fresh
echo "== warm-up"
cold; rm -rf "$OUT/cache"
t0=$(now); $PY -m app.runs.warm; echo "warm-up $(echo "$(now) - $t0" | bc) s"
t0=$(now); $PY -m app.runs.warm; echo "warm-up again $(echo "$(now) - $t0" | bc) s"
echo "== after the warm-up"
serve_ready; run_collision; serve_ready; run_collision
uptime
