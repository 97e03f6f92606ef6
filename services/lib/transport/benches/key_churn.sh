#!/bin/sh
# What ever-new object keys cost in memory: a router, a subscriber of churn/pose/* and a
# publisher of KEYS distinct keys (LIVE at a time), in MODE declared (a publisher declared per
# key, as fusion did) or put (Session::put, nothing declared). Prints each process's resident
# memory (and CPU time) at the start and the end.
#   services/lib/transport/benches/key_churn.sh BINARY MODE KEYS LIVE [PER_KEY [RATE]]
set -eu
bin=$1; mode=$2; keys=$3; live=$4; per_key=${5:-20}; rate=${6:-0}
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
ep="tcp/127.0.0.1:$port"
dir=$(mktemp -d)
"$bin" router "$ep" > "$dir/router" & r=$!
sleep 1
"$bin" sub "$ep" > "$dir/sub" & s=$!
sleep 2
"$bin" pub "$ep" "$mode" "$keys" "$live" "$per_key" "$rate" > "$dir/pub"
sleep 3
kill $r $s; wait $r $s 2>/dev/null || true
for f in router sub pub; do
  printf '%s: first %s, last %s\n' "$f" "$(head -1 "$dir/$f")" "$(tail -1 "$dir/$f")"
done
rm -rf "$dir"
