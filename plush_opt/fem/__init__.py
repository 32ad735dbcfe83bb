"""The finite-element model: ``Scene -> Mesh -> Model``. Meshing (Triangle,
graded towards corners and discs), the elements (P1, P2), and the energy
E(x; c) as a sum of the terms the scene needs (elastic body, pins, gravity,
tendons with their attachments, friction at via points), with exact
derivatives; the targets' objective O. Knows nothing of solvers.
"""
