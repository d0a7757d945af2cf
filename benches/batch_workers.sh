#!/usr/bin/env bash
# Throughput of `btfquilt batch` with 1, 2 and 4 worker processes on this
# machine (docs/measurements.md, "Batch jobs"). Run from the repository
# after `cargo build --release`:
#
#   bash benches/batch_workers.sh [WORK_DIR]
#
# Spot at 512² × the brick wall and the plaster × seeds 1–6 = 12 jobs, each
# with bake, two 400×300 renders and glTF. The shared artifacts are made
# once and copied into each run's folder; then W processes take shards
# I/W at once. Two rounds, 1 2 4 then 4 2 1 workers; each line gives the
# wall time of the whole set and the workers' peak RSS (/usr/bin/time).
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
B="$repo/target/release/btfquilt"
work="${1:-$(mktemp -d)}"
mkdir -p "$work" && cd "$work"
cp "$repo/data/spot_5.8k.obj" "$repo/data/brick_wall.png" "$repo/data/plaster_cracks.png" .
cat > plan.toml <<'PLAN'
[[mesh]]
path = "spot_5.8k.obj"
name = "spot"
[[sample]]
path = "brick_wall.png"
name = "wall"
[[sample]]
path = "plaster_cracks.png"
name = "plaster"
[atlas]
resolutions = [512]
[tile]
seeds = [1, 2, 3, 4, 5, 6]
[render]
width = 400
height = 300
lights = ["0.4,0.8,0.6", "-0.6,0.3,0.7"]
[outputs]
gltf = true
PLAN
rm -rf base
/usr/bin/time -f "shared stages: %e s, peak %M KB" "$B" batch plan.toml -o base --stages shared -q
run() { # workers threads round
    local w=$1 t=$2 out="w$1-$3"
    rm -rf "$out" && mkdir -p "$out" && cp -r base/inputs base/shared "$out/"
    local start end
    start=$(date +%s.%N)
    for i in $(seq 0 $((w - 1))); do
        /usr/bin/time -f "%M" -o "$out/peak$i" "$B" batch plan.toml -o "$out" --shard "$i/$w" --threads "$t" -q > /dev/null 2>&1 &
    done
    wait
    end=$(date +%s.%N)
    echo "workers $w, threads $t, round $3: $(echo "$end - $start" | bc) s for $(ls "$out/jobs" | wc -l) jobs;" \
        "peak RSS a worker $(cat "$out"/peak* | sort -n | tail -1) KB, all $(cat "$out"/peak* | paste -sd+ | bc) KB"
}
for round in 1 2; do
    if [ "$round" = 1 ]; then order="1 2 4"; else order="4 2 1"; fi
    for w in $order; do
        if [ "$w" = 1 ]; then run 1 2 "$round"; else run "$w" 1 "$round"; fi
    done
done
diff -r -x '*.jsonl' -x 'peak*' w1-1 w4-1 > /dev/null && echo "the folders of 1 and 4 workers are byte-identical"
