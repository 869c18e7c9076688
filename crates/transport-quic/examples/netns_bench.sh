#!/usr/bin/env bash
# Tiles from a "slave" to a "master" in two network namespaces joined by a veth
# pair, over TLS/TCP, plaintext TCP, QUIC (a stream per tile) and QUIC with one stream ("quic1"),
# with the link shaped by tc tbf and random loss from nftables (this kernel has
# no netem). Needs root, iproute2, nftables, ethtool. Creates and removes its
# own namespaces (isq_m, isq_s; 10.231.0.0/24 exists only between them).
#
#   cargo build --release -p isin-transport-quic --example loopback_bench
#   sudo crates/transport-quic/examples/netns_bench.sh 100mbit 10 5000 4
#        RATE (tc rate, or "none")  LOSS (per mille, each way)  TILES  WINDOW
set -euo pipefail
RATE=${1:-100mbit} LOSS=${2:-0} TILES=${3:-5000} WINDOW=${4:-4}
BIN=$(cd "$(dirname "$0")/../../.." && pwd)/target/release/examples/loopback_bench
[ -x "$BIN" ] || { echo "build it first: cargo build --release -p isin-transport-quic --example loopback_bench"; exit 1; }
for t in ip tc nft ethtool; do command -v $t >/dev/null || { echo "needs $t"; exit 1; }; done
down() { ip netns del isq_m 2>/dev/null || true; ip netns del isq_s 2>/dev/null || true; }
trap down EXIT
down
ip netns add isq_m; ip netns add isq_s
ip link add isq_vm type veth peer name isq_vs
ip link set isq_vm netns isq_m; ip link set isq_vs netns isq_s
ip -n isq_m addr add 10.231.0.1/24 dev isq_vm; ip -n isq_s addr add 10.231.0.2/24 dev isq_vs
for ns in isq_m isq_s; do ip -n $ns link set lo up; done
ip -n isq_m link set isq_vm up; ip -n isq_s link set isq_vs up
# Offloads off, so a drop hits one packet, not a 64 KB super-segment.
ip netns exec isq_m ethtool -K isq_vm tso off gso off gro off >/dev/null 2>&1 || true
ip netns exec isq_s ethtool -K isq_vs tso off gso off gro off >/dev/null 2>&1 || true
if [ "$RATE" != none ]; then
  tc -n isq_m qdisc add dev isq_vm root tbf rate "$RATE" burst 64kb latency 50ms
  tc -n isq_s qdisc add dev isq_vs root tbf rate "$RATE" burst 64kb latency 50ms
fi
if [ "$LOSS" != 0 ]; then
  for ns in isq_m isq_s; do
    ip netns exec $ns nft add table inet isq_loss
    ip netns exec $ns nft add chain inet isq_loss in '{ type filter hook input priority 0; }'
    ip netns exec $ns nft add rule inet isq_loss in iifname "isq_v*" numgen random mod 1000 lt "$LOSS" drop
  done
fi
echo "link $RATE, loss $LOSS per mille each way, $TILES tiles, $WINDOW in flight (CPU: slave process only)"
echo "| transport | tiles/s | CPU µs/tile | RTT p50 ms | RTT p99 ms | max ms | interface bytes/tile |"
echo "|---|---|---|---|---|---|---|"
for kind in tcp tcp-insecure quic quic1; do
  out=$(mktemp)
  ip netns exec isq_m "$BIN" serve 10.231.0.1:7900 "${kind%1}" >"$out" 2>&1 &
  server=$!
  for _ in $(seq 100); do grep -q listening "$out" && break; sleep 0.05; done
  fp=$(sed -n 's/^fp=//p' "$out")
  timeout 300 ip netns exec isq_s "$BIN" send 10.231.0.1:7900 "$kind" "$fp" "$TILES" "$WINDOW" || echo "| $kind | failed |"
  kill "$server"; wait "$server" 2>/dev/null || true
  rm -f "$out"
done
