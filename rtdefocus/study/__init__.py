"""The study wing: what measures and shows the product, never part of it.

``rtdefocus demo`` and ``rtdefocus eval`` (:mod:`rtdefocus.cli.study`) run from here, as do the
tests' and tools' scores. The product (calibration, compensation, playing) never imports this
package, so it can use heavier dependencies (scikit-image, matplotlib) than a plain install has.

Modules, one concept each:

* :mod:`.samples` — the test photographs, a text slide, :func:`~.samples.demo_images`;
* :mod:`.scores` — PSNR, SSIM, masks, edge counts, :func:`~.scores.score_image`;
* :mod:`.panels` — labelled side-by-side pictures;
* :mod:`.demo`, :mod:`.demo_surfaces`, :mod:`.demo_rooms` — ``rtdefocus demo`` and its pictures;
* :mod:`.eval`, :mod:`.eval_layouts`, :mod:`.evalreport` — ``rtdefocus eval`` (layouts,
  convergence) and its report;
* :mod:`.eval_video`, :mod:`.eval_video_report` — ``rtdefocus eval --video``: a moving clip
  through the live player, and its report;
* :mod:`.eval_drift`, :mod:`.eval_drift_report` — ``rtdefocus eval --drift``: the clip played
  while the set-up changes (a timeline of events), with and without the watcher and against
  an oracle re-calibrated at each event, and its report.
"""
