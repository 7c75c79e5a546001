"""Simulation requests are bounded at the request (issue 9 item 3): rig size, scene and option values,
the memory a render may take; and the API and the pages share one default (realistic 8-bit)."""

from __future__ import annotations

import dataclasses
import tracemalloc

import pytest

from metrology.captures.models import Capture
from metrology.captures.simulation import DEFAULT_PRESET, PRESETS, estimated_render_bytes
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, render_stack
from metrology.dashboard import forms
from metrology.jobs.models import Job
from tests.app.stacks import SMALL_RIG


def simulate(api, rig_id, **body):
    return api.post(f"/api/rigs/{rig_id}/captures/simulate/", {"role": "object", **body}, format="json")


@pytest.mark.parametrize(
    ("changes", "words"),
    [
        ({"width_px": 100_000, "height_px": 100_000}, "width_px"),
        ({"width_px": 4097}, "width_px"),
        ({"height_px": 5000}, "height_px"),
    ],
)
def test_rig_larger_than_the_image_limit_is_refused(api, changes, words):
    response = api.post("/api/rigs/", {**SMALL_RIG, **changes}, format="json")
    assert response.status_code == 400, response.content
    assert words in response.json()["error"]


def test_rig_size_limit_comes_from_the_setting(api, settings):
    settings.GCPS_MAX_IMAGE_SIDE_PX = 150
    response = api.post("/api/rigs/", SMALL_RIG, format="json")  # 160 x 120
    assert response.status_code == 400, response.content
    assert "width_px must be at most 150" in response.json()["error"]
    assert "GCPS_MAX_IMAGE_SIDE_PX" in response.json()["error"]


@pytest.mark.parametrize(
    ("body", "words"),
    [
        ({"scene": {"name": "plane", "z_mm": 1e308}}, "scene.z_mm"),
        ({"scene": {"name": "plane", "z_mm": 2000.0}}, "depth range"),
        ({"scene": {"name": "plane", "z_mm": -5000.0}}, "depth range"),
        ({"scene": {"name": "sphere", "radius_mm": 1e300}}, "scene.radius_mm"),
        ({"scene": {"name": "plane"}, "options": {"camera_defocus_px": 1e9}}, "options.camera_defocus_px"),
        ({"scene": {"name": "plane"}, "options": {"noise_grey": 1e308}}, "options.noise_grey"),
        ({"scene": {"name": "plane"}, "options": {"bit_depth": 8, "noise_grey": 100}}, "options.noise_grey"),
        ({"scene": {"name": "plane"}, "options": {"projector_defocus_codes": 1e6}}, "options.projector_defocus_codes"),
        ({"scene": {"name": "plane"}, "options": {"ambient": 50}}, "options.ambient"),
        ({"scene": {"name": "plane"}, "options": {"seed": 2**70}}, "options.seed"),
        ({"scene": {"name": "plane"}, "preset": "studio"}, "preset"),
    ],
)
def test_out_of_range_simulation_values_answer_400_naming_the_field(api, rig, body, words):
    response = simulate(api, rig["id"], **body)
    assert response.status_code == 400, response.content
    assert words in response.json()["error"], response.json()
    assert Job.objects.count() == 0 and Capture.objects.count() == 0


def test_simulation_of_an_existing_oversized_rig_is_refused_by_its_memory(api, rig, settings):
    """A rig stored before the size limit (or with a raised limit) still cannot ask for tens of GiB."""
    from metrology.rigs.models import Rig as RigRow

    row = RigRow.objects.get(pk=rig["id"])
    RigRow.objects.filter(pk=row.pk).update(parameters={**row.parameters, "width_px": 60_000, "height_px": 60_000})
    response = simulate(api, rig["id"], scene={"name": "plane"})
    assert response.status_code == 400, response.content
    message = response.json()["error"]
    assert "GiB" in message and "GCPS_MAX_SIMULATION_BYTES" in message, message
    assert Job.objects.count() == 0


def test_memory_limit_refuses_supersampling_that_would_exceed_it(api, rig, settings):
    rig_core = Rig.from_dict(SMALL_RIG)
    noise_free = SimulationOptions.noise_free_16bit()
    realistic = SimulationOptions.realistic_8bit()
    settings.GCPS_MAX_SIMULATION_BYTES = (
        estimated_render_bytes(rig_core, noise_free) + estimated_render_bytes(rig_core, realistic)
    ) // 2
    refused = simulate(api, rig["id"], scene={"name": "plane"}, preset="realistic")
    assert refused.status_code == 400, refused.content
    assert "GCPS_MAX_SIMULATION_BYTES" in refused.json()["error"]
    accepted = simulate(api, rig["id"], scene={"name": "plane"}, preset="noise-free")
    assert accepted.status_code == 202, accepted.content


@pytest.mark.parametrize("options", [SimulationOptions.noise_free_16bit(), SimulationOptions.realistic_8bit()])
def test_memory_estimate_bounds_the_measured_peak(options):
    """The estimate is at least the render's traced peak and at most three times it. A smaller
    sphere is rendered first with the same options: a process's first render of a scene with a
    footprint also loads the compiled kernels and tables (about 40 MB, 2100 B/px of this 160x120
    rig), which are not the render's own memory, so the traced peak no longer depends on what the
    process rendered before."""
    rig = Rig.from_dict(SMALL_RIG)
    render_stack(rig, make_scene("sphere", rig=rig, radius_mm=30.0), options)
    scene = make_scene("sphere", rig=rig)
    tracemalloc.start()
    try:
        render_stack(rig, scene, options)
        _current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    estimate = estimated_render_bytes(rig, options)
    assert peak <= estimate <= 3 * peak, (peak, estimate)


def test_api_and_pages_share_the_realistic_8_bit_default(api, rig):
    response = simulate(api, rig["id"], scene={"name": "plane", "z_mm": 10.0})
    assert response.status_code == 202, response.content
    stored = Capture.objects.get(pk=response.json()["id"]).parameters["options"]
    realistic = dataclasses.asdict(SimulationOptions.realistic_8bit())
    assert DEFAULT_PRESET == "realistic"
    assert dataclasses.asdict(SimulationOptions(**stored)) == realistic
    # the simulate form's initial noise choice is the same preset
    form_default = forms.NOISE_PRESETS[forms.SimulateCaptureForm.base_fields["noise"].initial][1]
    assert dataclasses.asdict(SimulationOptions(**form_default)) == realistic
    assert dataclasses.asdict(SimulationOptions(**PRESETS["noise-free"])) == dataclasses.asdict(SimulationOptions())


def test_options_override_the_preset(api, rig):
    response = simulate(api, rig["id"], scene={"name": "plane"}, preset="noise-free", options={"bit_depth": 8})
    assert response.status_code == 202, response.content
    stored = Capture.objects.get(pk=response.json()["id"]).parameters["options"]
    assert SimulationOptions(**stored) == SimulationOptions.noise_free_16bit(bit_depth=8)
