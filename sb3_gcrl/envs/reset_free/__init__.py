"""Reset-free task suite of thesis Ch. 3 (Section 3.7.1, Figure 3.3) as registered goal environments.

Each env is a gymnasium-robotics-style goal env (Dict obs ``observation``/``achieved_goal``/``desired_goal``,
vectorised ``compute_reward``, ``info["is_success"]``) that declares its task-relevant goals on the unwrapped
env: ``sample_initial_goal(rng)`` (rho_0) and ``sample_evaluation_goal(rng)`` (rho_g*);
``reset(options={"goal": g})`` commands goal ``g`` instead of a draw from rho_g*. The envs themselves are
episodic (registered with ``max_episode_steps`` = the evaluation horizon); reset-free training wraps them
with :class:`~sb3_gcrl.wrappers.ResetFreeWrapper`, which reads the hard-reset interval and the evaluation horizon
from the task table, :data:`sb3_gcrl.envs.tasks.TASKS`. PointUMaze, the eighth task, is ``GCRL/PointUMazeGoal-v0``.

=====================================  ==========  =================  =========================================
id                                     eval steps  hard reset every   source
=====================================  ==========  =================  =========================================
GCRL/ErgodicFetchPush-v0               50          1e5                IBC ergodic Fetch Push
GCRL/ErgodicFetchPickAndPlace-v0       50          1e5                IBC ergodic Fetch Pick&Place
GCRL/FetchPushHard-v0                  50          1e5                thesis Push (hard)
GCRL/FetchPickAndPlaceHard-v0          50          1e5                thesis Pick&Place (hard)
GCRL/AntArena-v0                       500         2e5                thesis Ant (from PEG's AntMaze)
GCRL/Tabletop-v0                       200         2e5                EARL Tabletop
GCRL/SawyerDoor-v0                     300         2e5                EARL Sawyer Door (needs metaworld)
GCRL/PointUMazeGoal-v0                 300         2e5                IBC PointUMaze (thesis: 100, larger maze)
=====================================  ==========  =================  =========================================
"""
