#!/usr/bin/env bash
# The main job, end to end on a laptop-class CPU with no download:
#   1. CALVIN-format play data from our scripted expert in the procedural CALVIN scene
#   2. conversion to a LeRobotDataset v3 with subgoal traces (verified against the source)
#   3. lerobot-train of the tiny SubgoalVLA preset (stage I, then stage II in the same run)
#   4. lerobot-eval on CALVIN's long-horizon chains (LH-MTLC) in our env
#   5. the LH-1..5 report (JSON + PNG)
# Every step resumes or is skipped when its output is already there, so an interrupted demo continues.
# Sizes can be changed with environment variables, e.g. DEMO_TASKS=200 DEMO_STEPS=5000 bash scripts/demo.sh
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup_venv.sh
export HF_HUB_OFFLINE=1 MPLBACKEND=Agg

OUT="${DEMO_DIR:-outputs/demo}"
TASKS="${DEMO_TASKS:-24}"           # expert-solved tasks recorded as play data
STEPS="${DEMO_STEPS:-300}"          # training steps
CHAINS="${DEMO_CHAINS:-3}"          # LH-MTLC chains evaluated
WORKERS="${DEMO_WORKERS:-2}"
mkdir -p "$OUT"

echo "== 1/5 generate CALVIN-format play data ($TASKS tasks) -> $OUT/calvin_native"
subgoalvla-generate-calvin --output "$OUT/calvin_native" --num-tasks "$TASKS" --seed 0 \
    --tasks-per-segment 4 --workers "$WORKERS"

echo "== 2/5 convert to a LeRobotDataset -> $OUT/dataset"
if [ ! -d "$OUT/dataset" ]; then
    resume=()
    [ -d "$OUT/dataset.partial" ] && resume=(--resume)
    subgoalvla-convert-calvin "$OUT/calvin_native" --repo-id local/calvin_demo --root "$OUT/dataset" \
        --workers "$WORKERS" --verify "${resume[@]}"
fi

echo "== 3/5 train SubgoalVLA (tiny preset, $STEPS steps) -> $OUT/train"
CKPT="$OUT/train/checkpoints/last/pretrained_model"
if [ -f "$CKPT/train_config.json" ] && [ ! -f "$OUT/train/.done" ]; then
    lerobot-train --config_path="$CKPT/train_config.json" --resume=true
elif [ ! -f "$OUT/train/.done" ]; then
    rm -rf "$OUT/train"
    lerobot-train --policy.type=subgoalvla --policy.preset=tiny --policy.push_to_hub=false \
        --policy.stage2_start_step=$((STEPS * 3 / 4)) \
        --dataset.repo_id=local/calvin_demo --dataset.root="$OUT/dataset" --dataset.video_backend=pyav \
        --output_dir="$OUT/train" --steps="$STEPS" --batch_size=8 --num_workers=1 \
        --log_freq=25 --save_freq="$STEPS" --seed=0
fi
touch "$OUT/train/.done"

echo "== 4/5 evaluate on $CHAINS LH-MTLC chains -> $OUT/eval"
rm -rf "$OUT/eval"
lerobot-eval --policy.path="$CKPT" --env.type=calvin --env.task=lh_mtlc --env.chain_stop="$CHAINS" \
    --env.results_path="$OUT/eval/results.jsonl" --eval.n_episodes=1 --eval.batch_size=1 \
    --eval.use_async_envs=false --output_dir="$OUT/eval" --seed=0

echo "== 5/5 report -> $OUT/report"
subgoalvla-calvin-report "$OUT/eval/results.jsonl" --output-dir "$OUT/report"
echo "Done: dataset $OUT/dataset, checkpoint $CKPT, eval videos $OUT/eval/videos, report $OUT/report/results.png"
