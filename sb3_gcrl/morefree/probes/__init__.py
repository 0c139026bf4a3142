"""Probes of the model-based MoReFree agent against ground truth, one module a family: the learned distance
(:mod:`~sb3_gcrl.morefree.probes.distance`), the learners (:mod:`~sb3_gcrl.morefree.probes.learners`), pi_G's
evaluation episodes beside the world model's prediction of them (:mod:`~sb3_gcrl.morefree.probes.rollouts`) and
goal holding (:mod:`~sb3_gcrl.morefree.probes.holding`). :mod:`sb3_gcrl.morefree.diagnostics` runs them all and
logs them during training.
"""
