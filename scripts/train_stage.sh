# Sourced by the end-to-end commands (scripts/demo.sh, scripts/metaworld.sh): their resumable training stage and
# its alternatives (a kept policy, LeRobot's baseline).
#   resumable_train OUT_DIR LOG LEROBOT_TRAIN_FLAGS...
# Runs lerobot-train into OUT_DIR (log in LOG); an interrupted run continues from its last checkpoint with
# --resume=true; a finished one (OUT_DIR/.done) is skipped.
resumable_train() {
    local out="$1" log="$2"
    shift 2
    local ckpt="$out/checkpoints/last/pretrained_model"
    mkdir -p "$(dirname "$log")"  # the log is written before lerobot-train creates any folder
    if [ -f "$ckpt/train_config.json" ] && [ ! -f "$out/.done" ]; then
        lerobot-train --config_path="$ckpt/train_config.json" --resume=true 2>&1 | tee -a "$log"
    elif [ ! -f "$out/.done" ]; then
        rm -rf "$out"
        lerobot-train "$@" --output_dir="$out" 2>&1 | tee "$log"
    fi
    touch "$out/.done"
}

# A trained policy to evaluate instead of training one (a run the study keeps: benchmarks/study/runs/).
#   kept_checkpoint VARIABLE_NAME PRETRAINED_MODEL_DIR
# Exits with one line naming the variable when the folder has no config.json; prints the path of the training
# log kept beside the folder (train.log; the reports read it where it exists).
kept_checkpoint() {
    if [ ! -f "$2/config.json" ]; then
        echo "$(basename "$0"): $1=$2 has no config.json; pass a pretrained_model folder" >&2
        exit 2
    fi
    echo "$(dirname "$2")/train.log"
}

# lerobot-train's mixed-precision flag where LeRobot has one (after 0.6.1), else nothing: LeRobot 0.6.1 takes the
# precision from the policy's dtype and rejects the flag; later versions take it from the flag only.
#   mixed_precision_flag bf16|fp16|no
mixed_precision_flag() {
    if python -c 'import dataclasses, sys; from lerobot.configs.train import TrainPipelineConfig as C
sys.exit("accelerator" not in {f.name for f in dataclasses.fields(C)})' 2>/dev/null; then
        echo "--accelerator.mixed_precision=$1"
    fi
}

# LeRobot's multi_task_dit as the study trains it (the flags' one home is benchmarks/study/multi_task.py), with
# random CLIP towers of laptop's size saved in CLIP_DIR once (no Hub here); prints the lerobot-train flags on
# one line, fails when the towers cannot be made (call it in an assignment, so that set -e sees the failure).
#   multi_task_dit_flags CLIP_DIR [random_clip.py ARGS...]
multi_task_dit_flags() {
    local clip="$1" flags
    shift
    if [ ! -f "$clip/config.json" ]; then
        python benchmarks/study/random_clip.py "$clip" "$@" > /dev/null || return 1
    fi
    flags="$(python -c 'import sys; sys.path.insert(0, "benchmarks/study")
from multi_task import MULTI_TASK_DIT_FLAGS; print(" ".join(MULTI_TASK_DIT_FLAGS))')" || return 1
    echo "$flags --policy.vision_encoder_name=$clip --policy.text_encoder_name=$clip"
}
