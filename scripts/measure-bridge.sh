#!/usr/bin/env bash
# Measures the UDP bridge under a junk flood: `serve` measures this machine's bare-loop floor
# first (--floor-seconds), then serves the example device at 1 kHz for SECONDS while another
# local port floods the server with random datagrams (FLOOD per second). Prints the report's
# timing, the stale periods and the counters, next to the floor. Usage:
#   scripts/measure-bridge.sh [SECONDS] [FLOOD] [--key]
set -euo pipefail
cd "$(dirname "$0")/.."
secs=${1:-60}
flood=${2:-10000}
keyed=${3:-}
port=47931
out=$(mktemp -d)
cargo build --quiet --release --bin touchfem --example udp_device
key_args=()
if [ "$keyed" = "--key" ]; then
  head -c 32 /dev/urandom > "$out/key"
  key_args=(--key "$out/key")
fi
target/release/touchfem serve cube --udp 127.0.0.1:$port --seconds "$((secs + 3))" \
  --floor-seconds "${FLOOR:-20}" --report "$out/report.json" "${key_args[@]}" 2> "$out/serve.log" &
server=$!
until grep -q "listening on udp" "$out/serve.log"; do sleep 0.2; done
python3 - "$port" "$flood" "$((secs + 2))" <<'PY' &
import os, random, socket, sys, time
port, rate, secs = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
t0, n = time.monotonic(), 0
while time.monotonic() - t0 < secs:
    s.sendto(os.urandom(random.randint(1, 200)), ("127.0.0.1", port)); n += 1
    ahead = n / rate - (time.monotonic() - t0)
    if ahead > 0: time.sleep(ahead)
print(f"flood: {n} datagrams in {time.monotonic() - t0:.1f} s", file=sys.stderr)
PY
flooder=$!
target/release/examples/udp_device 127.0.0.1:$port "$secs" "${key_args[@]}" > "$out/client.json"
wait $flooder
wait $server
python3 - "$out/report.json" "$out/client.json" <<'PY'
import json, sys
r, c = json.load(open(sys.argv[1])), json.load(open(sys.argv[2]))
h, f = r["haptic"], r.get("floor") or {}
keys = ["haptic_rate_hz", "missed_deadlines", "period_error_us_p999", "step_us_median"]
print("serve:", {k: h.get(k) for k in keys})
print("floor:", {k: f.get(k) for k in keys})
print("stale_periods", r["stale_periods"], "packets_rejected", r["packets_rejected"], "udp", r["udp"])
print("client:", {k: c[k] for k in ["ticks", "forces_received", "late", "rtt_us_p50", "rtt_us_p99", "max_force_n", "released", "rejected"]})
PY
