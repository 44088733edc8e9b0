"""The application wing: a problem run from its file to its outputs.

:mod:`~refine.run.stages` (the fused path, the refinement, one pass), :mod:`~refine.run.solve`
(every pass, and the placement repair), :mod:`~refine.run.write` (a run and its outputs),
:mod:`~refine.run.result` (what a run produced), :mod:`~refine.run.preflight` and
:mod:`~refine.run.check` (what is checked before solving), :mod:`~refine.run.batch` (many
problems), :mod:`~refine.run.outputs` (all-or-nothing writing), :mod:`~refine.run.evaluate`
(against a simulator's truth).
"""
