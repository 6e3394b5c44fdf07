# Sourced by scripts/metaworld.sh: its evaluation stage, LeRobot's own lerobot-eval in LeRobot's Meta-World env.
#   metaworld_evaluate CHECKPOINT EVAL_DIR FIRST_SEED EPISODES TASKS [LEROBOT_EVAL_FLAGS...]
# Evaluates the pretrained_model folder CHECKPOINT on each of TASKS (comma-separated, in that order), EPISODES
# episodes each from the whole number FIRST_SEED on, into EVAL_DIR/<task>/ (its log: EVAL_DIR/<task>.log).
# A task whose eval_info.json is there is skipped, so an interrupted stage continues with the next task; a task's
# half-written folder is removed and evaluated again. Results of another first seed belong in another EVAL_DIR,
# since a skipped task would otherwise keep the other seed's episodes.
metaworld_evaluate() {
    local ckpt="$1" eval_dir="$2" seed="$3" episodes="$4" tasks="$5"
    shift 5
    local task_list task
    IFS=, read -r -a task_list <<< "$tasks"
    mkdir -p "$eval_dir"
    for task in "${task_list[@]}"; do
        [ -f "$eval_dir/$task/eval_info.json" ] && continue
        rm -rf "$eval_dir/$task"
        lerobot-eval --policy.path="$ckpt" --env.type=metaworld --env.task="$task" \
            --eval.n_episodes="$episodes" --eval.batch_size=2 --eval.use_async_envs=true \
            --output_dir="$eval_dir/$task" --seed="$seed" "$@" > "$eval_dir/$task.log" 2>&1 \
            || { tail -5 "$eval_dir/$task.log" >&2; exit 1; }
        python - "$eval_dir/$task/eval_info.json" "$task" <<'EOF'
import json
import sys

overall = json.load(open(sys.argv[1]))["overall"]
print(f"   {sys.argv[2]}: {overall['pc_success']:.0f} % of {overall['n_episodes']} episodes")
EOF
    done
}
