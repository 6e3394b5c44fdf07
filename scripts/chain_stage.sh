# Sourced by scripts/demo.sh: its LH-MTLC stage, CALVIN's chains evaluated in parallel shards.
#   sharded_chains CHECKPOINT EVAL_DIR FIRST_CHAIN NUM_CHAINS SHARDS [LEROBOT_EVAL_FLAGS...]
# Evaluates chains FIRST_CHAIN .. FIRST_CHAIN+NUM_CHAINS-1 of CALVIN's official list in SHARDS lerobot-eval
# processes at once (one core each), shard k on its own slice into EVAL_DIR/lh_mtlc/shard<k>.jsonl, then joins
# the shards' lines into EVAL_DIR/lh_mtlc/results.jsonl for the reports. A stopped shard resumes
# (--env.resume: the chains already in its file are skipped), each continuation in its own folder and log; a
# complete shard is skipped; a finished stage (results.jsonl there) is skipped. Resume with the same SHARDS.
# LEROBOT_EVAL_FLAGS (e.g. the env's camera sizes) are passed to every shard's lerobot-eval.
sharded_chains() {
    local ckpt="$1" eval_dir="$2" first="$3" count="$4" shards="$5" k pids=()
    shift 5
    local results="$eval_dir/lh_mtlc/results.jsonl"
    [ -f "$results" ] && return 0
    mkdir -p "$eval_dir/lh_mtlc/runs"
    for ((k = 0; k < shards; k++)); do
        _chain_shard "$ckpt" "$eval_dir" $((first + count * k / shards)) $((first + count * (k + 1) / shards)) "$k" "$@" &
        pids+=($!)
    done
    for k in "${pids[@]}"; do
        wait "$k" || { echo "sharded_chains: a chain shard failed (its log's last lines above)" >&2; return 1; }
    done
    cat "$eval_dir"/lh_mtlc/shard*.jsonl > "$results.tmp" && mv "$results.tmp" "$results"
}

# _chain_shard CHECKPOINT EVAL_DIR LO HI K [FLAGS...]: chains [LO, HI) into shard K's file, resumed where it
# stopped.
_chain_shard() {
    local ckpt="$1" eval_dir="$2" lo="$3" hi="$4" k="$5" have=0
    shift 5
    local shard="$eval_dir/lh_mtlc/shard$k.jsonl"
    [ -f "$shard" ] && have=$(grep -c . "$shard")
    [ "$have" -ge $((hi - lo)) ] && return 0
    local run_dir="$eval_dir/lh_mtlc/runs/shard${k}_from_$have" log="$eval_dir/lh_mtlc_shard${k}_from_$have.log"
    rm -rf "$run_dir"
    lerobot-eval --policy.path="$ckpt" --env.type=calvin --env.task=lh_mtlc --env.chain_start="$lo" \
        --env.chain_stop="$hi" --env.results_path="$shard" --env.resume=true --eval.n_episodes=1 \
        --eval.batch_size=1 --eval.use_async_envs=false --output_dir="$run_dir" --seed=0 "$@" \
        > "$log" 2>&1 || { tail -5 "$log" >&2; return 1; }
}
