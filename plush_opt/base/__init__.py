"""The ground every layer stands on: the exception family, plane geometry,
sparse linear algebra (LDL^T with its inertia, low-rank updates), CasADi
kernels compiled to C, where the shipped files are, and files written
atomically. Imports no other part of plush_opt.
"""
