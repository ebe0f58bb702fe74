"""ltlnav planner: LTL formulas, Büchi automata, worlds, RRT*, TL-RRT* and mission decomposition.

Pure Python + numpy/scipy: no torch, no pybullet, no database.
"""
