"""The instrument's output Dataset: the surface variables kept, the chain's arrays added with
units and meanings, the instrument parameters as attributes, provenance (docs/interface.md §5)."""
from __future__ import annotations

import numpy as np

from .chain import PARTS

#: name -> (dims without scenario, units, long name)
VARIABLES = {
    "fine_time": (("fine_time",), "ns", "fine simulation grid (bin centres)"),
    "photon_rate": (("fine_time",), "ns-1", "expected photons per ns at the aperture "
                                            "(pulse and footprint kernel applied)"),
    "received_reflectance": (("fine_time",), "ns-1 sr-1",
                             "surface response seen through the pulse and footprint kernel, "
                             "specular and BF-direct returns scaled by their aperture fraction "
                             "(photon_rate per photon-per-sr of the lidar equation)"),
    "photons_at_aperture": (("part",), "1", "expected photons at the aperture per shot, by "
                                            "part of the surface response (whole response)"),
    "signal_photoelectrons": ((), "1", "expected signal photoelectrons per shot"),
    "diffuse_in_window": ((), "1", "fraction of the diffuse response inside the window"),
    "background_rate": ((), "ns-1", "background + dark primary electrons per ns"),
    "geometric_sigma": ((), "ns", "rms width of the footprint/slope/roughness kernel"),
    "lobe_half_angle": ((), "deg", "specular lobe half-angle lobe_factor x roughness"),
    "receiver_solid_angle": ((), "sr", "aperture seen from the ground, pi D^2 / (4 R^2)"),
    "aperture_fraction_specular": ((), "1", "fraction of the specular return entering the aperture"),
    "aperture_fraction_bf_direct": ((), "1", "fraction of a BF-direct return entering the aperture"),
    "speckle_modes": ((), "1", "speckle modes M (inf: no speckle)"),
    "sample_time": (("sample_time",), "ns", "nominal sample times; shot s samples at "
                                            "sample_time + sampling_phase[s]"),
    "signal_mv": (("shot", "sample_time"), "mV", "recorded electric signal: quantised ADC samples"),
    "expected_mv": (("sample_time",), "mV", "noiseless signal at sampling phase 0: mean "
                                            "voltage, clipped at saturation, not quantised"),
    "expected_analog_mv": (("fine_time",), "mV", "noiseless analog voltage before saturation"),
    "sampling_phase": (("shot",), "ns", "ADC sampling phase of the shot, U(0, interval)"),
    "speckle_factor": (("shot",), "1", "speckle factor of the shot, Gamma(M, 1/M)"),
    "pulse_fwhm": (("shot",), "ns", "transmitted pulse FWHM of the shot"),
    "detected": (("shot",), "", "matched-filter peak above threshold"),
    "range_time": (("shot",), "ns", "estimated arrival time relative to the surface (t = 0)"),
    "range_offset": (("shot",), "m", "range error c range_time / 2 (positive: farther)"),
    "pulse_width": (("shot",), "ns", "rms width of the recorded return"),
    "peak_mv": (("shot",), "mV", "largest sample of the shot"),
    "saturated": (("shot",), "", "a sample of the shot is at the clipped level (saturation or the top ADC code)"),
    "noise_mv": ((), "mV", "per-sample noise: electronic, background/dark shot noise, quantisation"),
    "electronic_noise_mv": ((), "mV", "electronic noise G_T i_n sqrt(B_eq)"),
    "baseline_mv": ((), "mV", "expected signal-free level (offset, dark and background)"),
    "threshold_mv": ((), "mV", "matched-filter threshold m noise_mv (unit-norm template)"),
    "saturation_mv": ((), "mV", "saturation voltage"),
    "template_width": ((), "ns", "rms width of the expected pulse p*g*h_e"),
    "excess_noise_factor": ((), "1", "APD excess noise factor F"),
    "mv_per_photoelectron": ((), "mV", "peak voltage per photoelectron for a Gaussian pulse of "
                                       "the template width, G_T q M / (sqrt(2 pi) sigma)"),
    "detection_probability": ((), "1", "closed-form P_D of the expected signal"),
    "false_alarm_probability": ((), "1", "closed-form false alarms per range gate"),
    "signal_counts": (("shot", "sample_time"), "1", "recorded photons per bin of each shot"),
    "expected_counts": (("sample_time",), "1", "expected photoelectrons per bin per shot, "
                                               "before dead time"),
    "expected_recorded_counts": (("sample_time",), "1", "expected recorded photons per bin per "
                                 "shot: after the dead times and the timing jitter, speckle "
                                 "averaged (an upper bound where the digital dead time exceeds "
                                 "twice the analog one)"),
    "dead_time_loss": ((), "1", "fraction of the expected photons in the window that the dead "
                               "times take (a lower bound where dead_time_loss_exact is 0)"),
    "dead_time_loss_exact": ((), "1", "1 where expected_recorded_counts is exact, 0 where the "
                                      "digital dead time exceeds twice the analog one"),
    "photon_time": (("shot", "photon"), "ns", "recorded time tags (NaN padded)"),
    "photon_count": (("shot",), "1", "recorded photons per shot"),
    "expected_photoelectrons": ((), "1", "expected photoelectrons per shot in the window"),
}
COORDS = ("fine_time", "sample_time")


def strip(ds):
    """``ds`` without the variables, coordinates and attributes of an earlier instrument run
    (so a result can be passed through another instrument)."""
    names = [n for n in list(VARIABLES) + ["shot", "part", "photon"] if n in ds.variables]
    out = ds.drop_vars(names)
    out.attrs = {k: v for k, v in ds.attrs.items() if not k.startswith("instrument_")}
    return out


def build(ds, results: list, params, scenario_dim: bool, extra_attrs: dict):
    """``ds`` with the chain's arrays added (stacked along ``scenario`` for a sweep)."""
    import xarray as xr

    out = strip(ds)
    first = results[0]
    shots = next((r[k].shape[0] for r in results for k in ("signal_mv", "signal_counts") if k in r), 0)
    coords = {"fine_time": ("fine_time", first["fine_time"], {"units": "ns"}),
              "sample_time": ("sample_time", first["sample_time"], {"units": "ns"}),
              "shot": ("shot", np.arange(shots)), "part": ("part", list(PARTS))}
    if "photon_time" in first:
        longest = max(r["photon_time"].shape[1] for r in results)
        for r in results:
            pad = longest - r["photon_time"].shape[1]
            if pad:
                r["photon_time"] = np.pad(r["photon_time"], ((0, 0), (0, pad)),
                                          constant_values=np.nan)
    for name, (dims, units, long_name) in VARIABLES.items():
        if name in COORDS or name not in first:
            continue
        values = [np.asarray(r[name]) for r in results]
        data = np.stack(values) if scenario_dim else values[0]
        full_dims = (("scenario",) if scenario_dim else ()) + dims
        attrs = {"long_name": long_name}
        if units:
            attrs["units"] = units
        out[name] = xr.Variable(full_dims, data, attrs)
    out = out.assign_coords({k: v for k, v in coords.items()
                             if k in ("fine_time", "sample_time", "part")
                             or (k == "shot" and shots)})
    out.attrs.update(params.describe())
    out.attrs["instrument_source"] = str(params.source)
    out.attrs.update(extra_attrs)
    return out
