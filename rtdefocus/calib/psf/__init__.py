"""The PSF stage: dots at sample points -> measured kernels -> the per-pixel kernel field.

Modules, one concept each:

* :mod:`.stage` — :func:`calibrate_psf`, :class:`PsfOptions`: the stage itself;
* :mod:`.pilot` — the pilot radius model and the fold code;
* :mod:`.sampling` — where the samples go (:func:`plan_samples`, :data:`LAYOUTS`);
* :mod:`.dots` — dot patterns, their capture and the kernels cut out of them;
* :mod:`.kernel_field` — the interpolation field (indices and weights per pixel);
* :mod:`.external` — :func:`calibrate_psf_from_dots`: the stage from another rig's dot captures;
* :mod:`.diagnostics` — the radius map and the stage's picture.
"""

from .stage import (
    FOLD,
    LAYOUTS,
    OPTIONS,
    Dots,
    Measurement,
    PsfOptions,
    PsfRun,
    RadiusModel,
    SamplePlan,
    calibrate_psf,
    equivalent_radius,
    fold_code,
    fold_segment,
    fold_segments,
    interpolation_field,
    iso_regions,
    measure_psfs,
    pack_patterns,
    pilot_radius,
    plan_samples,
    psf_diagnostics,
    psf_options,
    radius_map,
)

__all__ = ["calibrate_psf", "PsfOptions", "psf_options", "PsfRun", "Dots", "OPTIONS",
           "LAYOUTS", "FOLD", "pilot_radius", "iso_regions", "plan_samples", "measure_psfs",
           "interpolation_field", "psf_diagnostics", "radius_map", "equivalent_radius",
           "fold_segment", "fold_segments", "fold_code", "pack_patterns", "RadiusModel",
           "SamplePlan", "Measurement"]
