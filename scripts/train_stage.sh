# Sourced by the end-to-end commands (scripts/demo.sh, scripts/metaworld.sh): their resumable training stage.
#   resumable_train OUT_DIR LOG LEROBOT_TRAIN_FLAGS...
# Runs lerobot-train into OUT_DIR (log in LOG); an interrupted run continues from its last checkpoint with
# --resume=true; a finished one (OUT_DIR/.done) is skipped.
resumable_train() {
    local out="$1" log="$2"
    shift 2
    local ckpt="$out/checkpoints/last/pretrained_model"
    if [ -f "$ckpt/train_config.json" ] && [ ! -f "$out/.done" ]; then
        lerobot-train --config_path="$ckpt/train_config.json" --resume=true 2>&1 | tee -a "$log"
    elif [ ! -f "$out/.done" ]; then
        rm -rf "$out"
        lerobot-train "$@" --output_dir="$out" 2>&1 | tee "$log"
    fi
    touch "$out/.done"
}
