"""Every figure of hybrid-calib, drawn from result types and frames (layer 7: the commands and the
coming report call these; ``calib``, ``learned`` and lower layers never import them).

Modules, named for what they draw (each function writes one PNG atomically and returns its path):
``projection`` (points over a camera image: ``draw_projection``, ``draw_radar_on_frame``,
``draw_radar_truth``, ``render_overlay``), ``calibration`` (``plot_vehicle``: error / std over
frames and the step detector of a calibration run), ``network`` (``plot_frame``: one frame of the
network with its attention maps), ``training`` (``plot_history``: losses and validation errors per
epoch), ``evaluation`` (``plot_error_cdf``: error CDFs of an evaluation), ``report`` (the uncertainty
report's figures: ``draw_before_after``, ``plot_estimate_bands``, ``plot_residual_histograms``),
``fleet`` (``draw_fleet``, ``plot_fleet``: every vehicle's offset from the design mount). ``figure``
holds the shared matplotlib set-up and the atomic save.
"""
