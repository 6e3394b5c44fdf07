#!/usr/bin/env bash
# SubgoalVLA on Meta-World, end to end, through LeRobot's own env and data layout (docs/metaworld.md):
#   1. Meta-World's scripted experts recorded in LeRobot's published layout (subgoalvla-generate-metaworld)
#   2. the state history and subgoal traces added (subgoalvla-add-traces; the paper's frame counts, see below)
#   3. lerobot-train of SubgoalVLA (laptop preset on a CPU), stage I then stage II in one run
#   4. lerobot-eval --env.type=metaworld --env.task=<task> for every task, LeRobot's env unchanged
#   5. the report: success per task with its interval, loss curves, links to the rollout videos
# Defaults: the 10 MT10 tasks, 10 expert episodes each, 2000 steps x 32, 10 evaluation episodes per task on
# seeds 1000+ (never used for data: data seeds derive from --seed 0). Time on 2 CPU cores: generation ~1 h
# (rendering 480 px is 92 % of it, ~4 steps/s per worker), training ~25 min, evaluation ~10 min per task (an
# unsolved episode runs LeRobot's 500-step limit). Expected result: not measured yet at these sizes (see
# docs/RESULTS.md); MW_TASKS / MW_EPISODES / MW_STEPS / MW_EVAL_EPISODES / MW_WORKERS / MW_DIR set the sizes.
# Every stage resumes or is skipped when its output is there, so an interrupted run continues.
# Window: Meta-World's expert episodes last 45-90 steps at a nominal 80 fps, so the fps-scaled window (up to 58
# steps ahead) would span most of an episode; the paper's frame counts (trace 14-21 steps ahead) are used.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup_venv.sh
source scripts/train_stage.sh
export MPLBACKEND=Agg MUJOCO_GL="${MUJOCO_GL:-egl}" HF_HUB_OFFLINE="${HF_HUB_OFFLINE:-1}"
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" MKL_NUM_THREADS="${MKL_NUM_THREADS:-1}"

MT10=(reach-v3 push-v3 pick-place-v3 door-open-v3 drawer-open-v3 drawer-close-v3 button-press-topdown-v3
    peg-insert-side-v3 window-open-v3 window-close-v3)
read -r -a TASKS <<< "${MW_TASKS:-${MT10[*]}}"
EPISODES="${MW_EPISODES:-10}"            # expert episodes per task
STEPS="${MW_STEPS:-2000}"                # training steps (stage II for the last fifth)
EVAL_EPISODES="${MW_EVAL_EPISODES:-10}"  # evaluation episodes per task
WORKERS="${MW_WORKERS:-2}"
OUT="${MW_DIR:-outputs/metaworld}"
REPO=local/metaworld
mkdir -p "$OUT"
started=$(date +%s)
stage() { echo "== [$(( ($(date +%s) - started) / 60 )) min] $*"; }

stage "1/5 record ${#TASKS[@]} tasks x $EPISODES expert episodes -> $OUT/raw"
if [ ! -f "$OUT/raw/meta/info.json" ]; then
    subgoalvla-generate-metaworld --output-root "$OUT/raw" --repo-id "$REPO" --tasks "$(IFS=,; echo "${TASKS[*]}")" \
        --episodes-per-task "$EPISODES" --seed 0 --workers "$WORKERS"
fi

stage "2/5 add state history and subgoal traces -> $OUT/dataset"
[ -d "$OUT/dataset" ] || subgoalvla-add-traces --repo-id "$REPO" --root "$OUT/raw" --output-root "$OUT/dataset" \
    --trace-start 14 --stride 1

stage "3/5 train SubgoalVLA (laptop preset, $STEPS steps x 32) -> $OUT/train (log: $OUT/train.log)"
CKPT="$OUT/train/checkpoints/last/pretrained_model"
resumable_train "$OUT/train" "$OUT/train.log" --policy.type=subgoalvla --policy.preset=laptop \
    --policy.push_to_hub=false --policy.device=cpu --policy.stage2_start_step=$((STEPS * 4 / 5)) \
    --dataset.repo_id="$REPO" --dataset.root="$OUT/dataset" --dataset.video_backend=pyav \
    --steps="$STEPS" --batch_size=32 --num_workers=1 --log_freq=50 --save_freq=$((STEPS / 4)) --seed=0 \
    --wandb.enable=false

stage "4/5 evaluate ${#TASKS[@]} tasks x $EVAL_EPISODES episodes in LeRobot's Meta-World env -> $OUT/eval"
for task in "${TASKS[@]}"; do
    if [ ! -f "$OUT/eval/$task/eval_info.json" ]; then
        rm -rf "$OUT/eval/$task"
        mkdir -p "$OUT/eval"
        lerobot-eval --policy.path="$CKPT" --env.type=metaworld --env.task="$task" \
            --eval.n_episodes="$EVAL_EPISODES" --eval.batch_size=2 --eval.use_async_envs=true \
            --output_dir="$OUT/eval/$task" --seed=1000 > "$OUT/eval/$task.log" 2>&1 \
            || { tail -5 "$OUT/eval/$task.log" >&2; exit 1; }
        python -c "import json,sys; o=json.load(open(sys.argv[1]))['overall']; print(f'   {sys.argv[2]}: {o[\"pc_success\"]:.0f} % of {o[\"n_episodes\"]} episodes')" \
            "$OUT/eval/$task/eval_info.json" "$task"
    fi
done

stage "5/5 report -> $OUT/report"
subgoalvla-demo-report --train-log "$OUT/train.log" --eval-dir "$OUT/eval" --output-dir "$OUT/report"
stage "done: report $OUT/report/README.md"
