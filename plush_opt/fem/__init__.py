"""The finite-element model: ``Scene -> Mesh -> Model``. Meshing (Triangle,
graded towards corners and discs), the elements (P1, P2), and the energy
E(x; c) as a sum of the terms the scene needs (elastic body, pins, gravity,
tendons with their attachments, friction at via points, contact with the
floor, obstacles and the body itself), with exact derivatives and the 2D
contact geometry; the targets' objective O. Knows nothing of solvers.
"""
