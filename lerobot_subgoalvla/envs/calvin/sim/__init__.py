"""The CALVIN simulator: pybullet world, desk scene, Panda robot, cameras and CALVIN's asset files.

``CalvinSimulation`` (``simulation.py``) owns one pybullet client; ``scene.py`` loads the desk and its
fixtures (procedural or CALVIN's URDFs via ``assets.py`` / ``procedural_table.py``), ``robot.py`` the arm and
its IK, ``cameras.py`` the static and gripper views. Nothing here knows about tasks, experts or LeRobot.
"""

from lerobot_subgoalvla.envs.calvin.sim.stdio import quiet_c_output

with quiet_c_output():  # its "pybullet build time" banner, once per process
    import pybullet  # noqa: F401
