# Sourced by scripts/metaworld.sh: its first stage, the expert episodes it trains on.
#   metaworld_episodes OUT REPO TASKS EPISODES ACTION_NOISE WORKERS MORE_TASKS MORE_EPISODES
# Writes OUT/raw, a LeRobotDataset of EPISODES successful expert episodes of each of TASKS (comma-separated),
# recorded by subgoalvla-generate-metaworld from seed 0. With MORE_TASKS (comma-separated, a subset of TASKS)
# those tasks get MORE_EPISODES more episodes, recorded from seed 1 (other start states) into OUT/raw_more,
# while the base episodes go to OUT/raw_base; LeRobot's own `lerobot-edit-dataset` merges the two into
# OUT/raw. The merge writes OUT/raw.merging and renames it when complete, so OUT/raw is never half-written;
# every step is skipped when its dataset is there, and an interrupted recording resumes (the generator's own).
metaworld_episodes() {
    local out="$1" repo="$2" tasks="$3" episodes="$4" noise="$5" workers="$6" more_tasks="$7" more="$8"
    [ -f "$out/raw/meta/info.json" ] && return 0
    local common=(--repo-id "$repo" --action-noise "$noise" --workers "$workers")
    if [ -z "$more_tasks" ]; then
        subgoalvla-generate-metaworld --output-root "$out/raw" --tasks "$tasks" --episodes-per-task "$episodes" \
            --seed 0 "${common[@]}"
        return 0
    fi
    [ -f "$out/raw_base/meta/info.json" ] || subgoalvla-generate-metaworld --output-root "$out/raw_base" \
        --tasks "$tasks" --episodes-per-task "$episodes" --seed 0 "${common[@]}"
    [ -f "$out/raw_more/meta/info.json" ] || subgoalvla-generate-metaworld --output-root "$out/raw_more" \
        --tasks "$more_tasks" --episodes-per-task "$more" --seed 1 "${common[@]}"
    rm -rf "$out/raw.merging"
    lerobot-edit-dataset --operation.type=merge --operation.repo_ids="[$repo,$repo]" \
        --operation.roots="[$out/raw_base,$out/raw_more]" --new_repo_id="$repo" --new_root="$out/raw.merging"
    mv "$out/raw.merging" "$out/raw"
}
