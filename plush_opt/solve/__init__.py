"""Forward solves on a model: certified equilibria (Newton, IPOPT as the
cross-check), moves that stay on a stable branch, paths where the pose
depends on history (friction at via points and at contacts), implicit sensitivities from the kept
factorisation, the mesh an accuracy needs, and the result file of a pose.
"""
