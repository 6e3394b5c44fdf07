"""Subpackage of lerobot_subgoalvla."""
