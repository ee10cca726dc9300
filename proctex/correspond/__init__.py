"""Correspondence: from every shape's parts to the template's.

``mvc`` (mean value coordinates), ``cage`` (the per-pair cage solver), ``cpd`` (Coherent Point Drift,
a baseline), ``corrnet`` (ProcCorrNet) and ``dense`` (one interface for all methods, shape by
shape). Imports ``geometry``, ``texture`` and the base modules only.
"""
