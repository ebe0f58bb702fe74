"""ltlnav envs: robots (dynamics) and rewards as Gymnasium environments.

Importing the package stays light (no torch, no pybullet) so that the ``robot:`` section of a
mission (``envs.spec``) can be validated anywhere.
"""
