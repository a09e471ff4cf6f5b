"""Ground-air team planning with collaborative localization (paper 002, Butzke et al.).

State lattice with controller-based motion primitives (SLC, 002 §III) for a drone with weak
self-localization and a well-localized ground robot (UGV), searched with full-dimensional ARA*
(the baseline) or with Planning with Adaptive Dimensionality (PAD, 002 §IV). The output is a
`TeamPlan`: per-robot controller sequences with synchronisation points (002 §IV-E).
See docs/collab.md.
"""
