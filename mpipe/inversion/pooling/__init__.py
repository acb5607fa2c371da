"""The note as one experiment: a pooled fit of a note's windows (``inversion.pooling: note``).

The per-window fit (:mod:`mpipe.inversion.fit.window`) gives every 20 ms window its own eight
parameters. Here the reed's slow parameters (k, S, lam, m, g, k_c, and y_c when searched)
are shared by a note's windows (or by each stretch of ``inversion.pooling_stretch_s`` of a
long note) and the player's fast ones (p_m, y_m) stay per window. One Levenberg-Marquardt
over the note refines the per-window answers, from the note's median of its ok windows for
the slow parameters and each window's own fast values.

- ``arrow``: the bordered block-diagonal (block-arrow) normal equations of the joint fit,
  solved by eliminating each window's fast block (Schur complement: cost linear in the
  number of windows), and the joint sandwich covariance by the same elimination;
- ``note_fit``: the joint Levenberg-Marquardt over one note's window objectives
  (:class:`mpipe.inversion.fit.objective.F2Objective`, their Jacobians from the model's forward
  sensitivities), and each window's noise gram at the harmonics
  (:mod:`mpipe.inversion.trust.harmonics`);
- ``take_pooling``: every note of a tracked take pooled, the windows table rewritten with
  the pooled values and their uncertainty columns, statuses classified again.

It may import the floor (settings) and the rooms below it: preparation, trust, table and
fit; the whole take (``whole_take``) calls it.

See docs/uncertainty.md, "Pooling a note's windows".
"""
