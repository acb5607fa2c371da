"""The normal equations of a joint fit over many windows: their blocks and their elimination.

The take's one fit (:mod:`mpipe.inversion.whole_take.estimator`) has three tiers of
parameters: each window's fast ones (the player's p_m, y_m), each note's slow ones (the
reed's k, S, lam, m, g, k_c, y_c) and the take's temperature. Its Gauss-Newton normal
matrix is sparse with nested borders; eliminating the windows' blocks, then the notes'
(bundle adjustment's reduced system), makes a step and the sandwich covariance cost time
linear in the number of windows.

- ``take_system``: the take's system (windows, notes, the take), its step, an unknown held
  (an estimate on a bound), and its one sandwich covariance.

It may import the floor (settings) and the rooms below it: preparation, trust, table and
fit; the whole take (``whole_take``) calls it.

See docs/estimator.md.
"""
