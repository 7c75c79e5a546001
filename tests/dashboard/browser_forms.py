"""Filling the dashboard's forms in the browser tests (Playwright pages): log in, simulate a capture or
a stage series on a rig's captures page, and wait for a job's progress page to move on."""

from __future__ import annotations

from tests.browser import POLL_MS
from tests.conftest import PASSWORD


def log_in(page, base: str, username: str = "alice") -> None:
    page.goto(f"{base}/login/")
    page.fill("#id_username", username)
    page.fill("#id_password", PASSWORD)
    page.click("button[type=submit]")
    page.wait_for_url(f"{base}/")


def wait_for_job(page, next_url_glob: str) -> None:
    """From a job's progress page, wait until it moved on to ``next_url_glob`` (the job done); fail
    with the job's error when it failed instead."""
    page.wait_for_function(
        "() => !document.querySelector('.js-job') || document.querySelector('.js-job [data-status=failed]')",
        polling=POLL_MS,
    )
    failed = page.locator(".js-job [data-status=failed]")
    assert not failed.count(), page.locator(".js-error").inner_text()
    page.wait_for_url(next_url_glob)


def wait_until_shown_done(page) -> None:
    """On a result page that was rendered while its job ran: wait until the page shows the job done
    after its own reload (the progress bar's script reloads the page 0.4 s after the badge turns
    done; a navigation started in between is aborted by that reload)."""
    page.locator("h1 .badge.done").wait_for()
    page.locator(".js-job").wait_for(state="detached")


def simulate(page, rig_url: str, scene: str, z: str = "", noise: str = "none", seed: str = "1") -> None:
    """Simulate one capture of ``scene`` on the rig's captures page and wait until it is stored."""
    page.goto(f"{rig_url}captures/")
    page.select_option("#id_simulate-scene", scene)
    page.fill("#id_simulate-z_mm", z)
    page.select_option("#id_simulate-noise", noise)
    page.fill("#id_simulate-seed", seed)
    page.click("form:has(input[value=simulate]) button[type=submit]")
    page.wait_for_url("**/jobs/*/**")  # the progress page...
    wait_for_job(page, f"{rig_url}captures/")  # ...which moves on once the job is done


def simulate_stage_series(page, rig_url: str, z_to: str, step: str, repeats: str, noise: str = "low") -> None:
    """Simulate a stage series from Z_in 0 to ``z_to`` mm and wait for its characterization form."""
    page.goto(f"{rig_url}captures/")
    page.fill("#id_stage-z_from_mm", "0")
    page.fill("#id_stage-z_to_mm", z_to)
    page.fill("#id_stage-z_step_mm", step)
    page.fill("#id_stage-repeats", repeats)
    page.select_option("#id_stage-noise", noise)
    page.click("form:has(input[value=stage]) button[type=submit]")
    page.wait_for_url("**/jobs/*/**")
    wait_for_job(page, "**/characterizations/new/?rig=*&session=*")  # the series' last job lands on its form


def create_rig(page, name: str, width: str = "320", height: str = "240") -> str:
    """Fill the Rigs page's "New rig" form (the page already open) with the paper's values at
    ``width`` x ``height`` px; returns the new rig's page URL."""
    page.fill("#id_name", name)
    page.fill("#id_width_px", width)
    page.fill("#id_height_px", height)
    page.click("text=Create rig")
    page.wait_for_url("**/rigs/*/")
    return page.url
