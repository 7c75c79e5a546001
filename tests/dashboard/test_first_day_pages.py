"""What a real rig's first day showed (issue 21, item 5), on the pages: one format for valid
pixels, the upload's confirmation, the maps' robust colours."""

from __future__ import annotations

import re
from html import unescape

from django.core.files.uploadedfile import SimpleUploadedFile

from metrology.measurements.models import Measurement
from tests.app.stacks import SMALL_RIG, plane_zip
from tests.dashboard.helpers import figure_data


def test_valid_pixels_are_a_percentage_on_lists_and_detail_pages(client_alice, rig, captures, run_jobs):
    reference, obj = captures
    with run_jobs():
        client_alice.post("/measurements/new/", {"rig": rig.pk, "reference": reference.pk, "object": obj.pk})
    measurement = Measurement.objects.get(rig=rig)
    shown = f"{100 * measurement.statistics['valid_fraction']:.1f} %"
    assert shown in client_alice.get("/measurements/").content.decode()
    detail = client_alice.get(f"/measurements/{measurement.pk}/").content.decode()
    assert f"<dt>Valid pixels</dt><dd>{shown}</dd>" in detail
    capture_page = unescape(client_alice.get(f"/captures/{obj.pk}/").content.decode())
    total = SMALL_RIG["width_px"] * SMALL_RIG["height_px"]
    assert '<th class="num">Valid pixels</th>' in capture_page
    assert re.search(rf"<td class=\"num\">\d+\.\d % \([\d,]+ of {total:,} px\)</td>", capture_page), capture_page


def test_the_height_map_is_coloured_between_p1_and_p99_with_the_full_range_stated(
    client_alice, rig, captures, run_jobs
):
    reference, obj = captures
    with run_jobs():
        client_alice.post("/measurements/new/", {"rig": rig.pk, "reference": reference.pk, "object": obj.pk})
    measurement = Measurement.objects.get(rig=rig)
    html = client_alice.get(f"/measurements/{measurement.pk}/").content.decode()
    heatmap = figure_data(html, "height_map")
    meta = heatmap["layout"]["meta"]
    trace = heatmap["data"][0]
    assert [trace["zmin"], trace["zmax"]] == meta["colour_range_mm"]
    low, high = meta["full_range_mm"]
    assert low <= trace["zmin"] < trace["zmax"] <= high
    assert "colours p1-p99" in trace["colorbar"]["title"]["text"] and "full range" in trace["colorbar"]["title"]["text"]
    surface = figure_data(html, "surface")
    assert surface["layout"]["scene"]["zaxis"]["range"] == surface["layout"]["meta"]["z_shown_mm"]


def test_an_upload_confirms_the_capture_and_the_codec_it_is_decoded_with(client_alice, rig):
    page = unescape(client_alice.get(f"/rigs/{rig.pk}/captures/").content.decode())
    assert "without a codec.json, the rig's default codec (gcps-v1) describes the frames" in page
    response = client_alice.post(
        f"/rigs/{rig.pk}/captures/",
        {"action": "upload", "upload-role": "reference", "upload-file": SimpleUploadedFile("r.zip", plane_zip())},
        follow=True,
    )
    capture = rig.captures.get()
    html = unescape(response.content.decode())
    width, height = SMALL_RIG["width_px"], SMALL_RIG["height_px"]
    assert (
        f"Stored capture #{capture.pk} (reference plane, r.zip): {width} x {height} px, 8 bit, decoded with "
        "gcps-v1, the rig's default codec (used when the zip has no codec.json)."
    ) in html
