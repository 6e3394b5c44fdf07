"""SubgoalVLA policy: config, model pieces, LeRobot policy and processors.

Dimension legend, the same letters in every module of this package (each module's docstring lists the ones it
uses):

| letter | meaning |
|---|---|
| ``B`` | batch (or parallel envs at inference) |
| ``h`` | state-history steps (``state_history_len``) |
| ``M`` | subgoal-trace steps (``subgoal_trace_len``) |
| ``N`` | action-chunk steps (``chunk_size``) |
| ``p`` | proprioceptive state size, the dataset's ``observation.state`` (15 for CALVIN, 4 for Meta-World) |
| ``A`` | action size, the dataset's ``action`` (7 for CALVIN, 4 for Meta-World) |
| ``S`` | VLM tokens: image placeholders + instruction (the tokenised sequence) |
| ``E`` | VLM (LLM) hidden size, also the aggregators' output width |
| ``D`` | a module's own width: DiT hidden size, or an aggregator's internal width |
| ``Q`` | aggregator query tokens (h for the planner, h + M for the generator) |
| ``K`` | VLM tokens kept by the top-k pooling ablations |
| ``T`` | tokens of a diffusion sample (M for the planner, N for the generator) |
| ``X`` | feature size of those tokens (p or A) |
| ``Tc``, ``Dc`` | conditioning tokens and their width |
| ``R`` | repeated diffusion steps per training sample |
| ``V`` | camera views the policy reads (``camera_keys``) |
| ``H``, ``W`` | camera image size; ``I`` the vision tower's square input side |
"""
