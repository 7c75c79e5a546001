"""Server-side render time of every dashboard page for a 1280x1024 measurement (issue 5: < 1 s each).

    .venv/bin/python benchmarks/pages.py                  # 1280x1024, median of 7 GETs per page
    .venv/bin/python benchmarks/pages.py --size 640x480 --repeats 5 --json out.json

Everything happens in a temporary folder (SQLite database and media), on the embedded default
(jobs run in-process): a user, a 1280x1024 rig, simulated reference / object (two spheres) /
master block / stage series (3 positions x 2 repeats) captures, a measurement, a least-squares
calibration and a characterization, all made through the same services the pages and the REST API
call. Each page is then fetched with Django's test client (the full request path: middleware,
login session, view, selectors, figure building, template) and the median wall time is printed.
The first GET of each page is a warm-up and is not counted (it also fills the sensitivity cache;
its time is reported separately as ``cold``).
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def configure(folder: Path) -> None:
    """Environment for a throw-away embedded instance in ``folder`` (before Django starts)."""
    for name in ("DATABASE_URL", "REDIS_URL", "CELERY_BROKER_URL", "MEDIA_ROOT"):
        os.environ.pop(name, None)
    os.environ.update(
        GCPS_VAR_DIR=str(folder),
        DEBUG="0",
        SECRET_KEY=secrets.token_urlsafe(60),
        SECURE_SSL_REDIRECT="0",
        ALLOWED_HOSTS="testserver,localhost",
        STATIC_ROOT=str(folder / "static"),
        LOG_LEVEL="WARNING",
        DJANGO_SETTINGS_MODULE="metrology.settings",
    )


def build(width: int, height: int) -> dict:
    """Create the objects through the services; returns ids and how long each step took."""
    from django.core.management import call_command

    from metrology.accounts.services import create_user_with_token
    from metrology.calibrations.services import request_calibration
    from metrology.captures.services import create_session, request_simulated_capture
    from metrology.characterizations.services import request_characterization
    from metrology.measurements.services import request_measurement
    from metrology.rigs.services import create_rig

    call_command("migrate", verbosity=0)
    user, _key = create_user_with_token(username="bench")
    rig = create_rig(
        owner=user,
        data={
            "name": f"bench {width}x{height}",
            "L_mm": 1022.0,
            "d_mm": 352.0,
            "alpha_rad": 0.332,
            "fw_mm": 500.0,
            "nlp": 128,
            "width_px": width,
            "height_px": height,
        },
    )
    options = {"bit_depth": 8, "noise_grey": 1.0}
    steps: dict[str, float] = {}

    def timed(name, call):
        start = time.perf_counter()
        out = call()
        steps[name] = time.perf_counter() - start
        out.refresh_from_db()
        if out.job and out.job.status != "done":
            raise SystemExit(f"{name}: job {out.job.pk} is {out.job.status}: {out.job.error}")
        return out

    def simulate(role, scene, seed, **extra):
        return request_simulated_capture(
            owner=user, rig=rig, role=role, scene=scene, options={**options, "seed": seed}, **extra
        )

    reference = timed("simulate reference", lambda: simulate("reference", {"name": "reference"}, 1))
    obj = timed("simulate object", lambda: simulate("object", {"name": "two_spheres"}, 2))
    master = timed("simulate master", lambda: simulate("master", {"name": "block", "top_mm": 40.0}, 3))
    session = create_session(owner=user, rig=rig, name="stage 0-8 mm")
    start = time.perf_counter()
    for index, z in enumerate((0.0, 4.0, 8.0)):
        for repeat in range(2):
            simulate(
                "stage", {"name": "stage"}, 10 + 2 * index + repeat, z_in_mm=z, repeat=repeat, session_id=session.pk
            )
    steps["simulate stage series (6)"] = time.perf_counter() - start
    measurement = timed(
        "measurement", lambda: request_measurement(owner=user, rig=rig, reference_id=reference.pk, object_id=obj.pk)
    )
    calibration = timed(
        "calibration (lsq)",
        lambda: request_calibration(
            owner=user,
            rig=rig,
            reference_id=reference.pk,
            master_id=master.pk,
            master_height_mm=40.0,
            method="lsq",
            initial={"L_mm": 1080.0, "alpha_rad": 0.4871},
        ),
    )
    characterization = timed(
        "characterization",
        lambda: request_characterization(owner=user, rig=rig, reference_id=reference.pk, session_id=session.pk),
    )
    return {
        "user": user,
        "rig": rig.pk,
        "measurement": measurement.pk,
        "calibration": calibration.pk,
        "characterization": characterization.pk,
        "job": measurement.job_id,
        "steps": steps,
    }


def pages(ids: dict) -> dict[str, str]:
    rig = ids["rig"]
    return {
        "home": "/",
        "rigs": "/rigs/",
        "rig detail": f"/rigs/{rig}/",
        "rig captures": f"/rigs/{rig}/captures/",
        "rig sensitivity": f"/rigs/{rig}/sensitivity/",
        "captures": "/captures/",
        "measurements": "/measurements/",
        "new measurement": f"/measurements/new/?rig={rig}",
        "measurement detail": f"/measurements/{ids['measurement']}/",
        "measurement detail, row 100": f"/measurements/{ids['measurement']}/?row=100",
        "calibrations": "/calibrations/",
        "new calibration": f"/calibrations/new/?rig={rig}",
        "calibration detail": f"/calibrations/{ids['calibration']}/",
        "characterizations": "/characterizations/",
        "new characterization": f"/characterizations/new/?rig={rig}",
        "characterization detail": f"/characterizations/{ids['characterization']}/",
        "job progress": f"/jobs/{ids['job']}/",
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", default="1280x1024", help="WIDTHxHEIGHT of the rig (default 1280x1024)")
    parser.add_argument("--repeats", type=int, default=7, help="timed GETs per page (median reported)")
    parser.add_argument("--limit-ms", type=float, default=1000.0, help="fail if a page's median exceeds this")
    parser.add_argument("--json", type=Path, help="also write the numbers here")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))

    with tempfile.TemporaryDirectory(prefix="gcps-bench-pages-") as tmp:
        configure(Path(tmp))
        import django

        django.setup()
        from django.test import Client

        print(f"building a {width}x{height} rig and its results in {tmp} ...", flush=True)
        ids = build(width, height)
        for name, seconds in ids["steps"].items():
            print(f"  {name:28s} {seconds:7.2f} s")
        client = Client()
        client.force_login(ids["user"])
        rows = []
        for name, url in pages(ids).items():
            start = time.perf_counter()
            response = client.get(url)
            cold = time.perf_counter() - start
            if response.status_code != 200:
                raise SystemExit(f"{url} answered {response.status_code}")
            times = []
            for _ in range(args.repeats):
                start = time.perf_counter()
                response = client.get(url)
                times.append(time.perf_counter() - start)
            rows.append(
                {
                    "page": name,
                    "url": url,
                    "median_ms": 1000 * statistics.median(times),
                    "max_ms": 1000 * max(times),
                    "cold_ms": 1000 * cold,
                    "kb": len(response.content) / 1024,
                }
            )
    print(f"\nserver-side render time, {width}x{height} measurement, median of {args.repeats} GETs")
    print(f"{'page':30s} {'median ms':>10s} {'max ms':>8s} {'cold ms':>8s} {'HTML kB':>8s}")
    for row in rows:
        print(f"{row['page']:30s} {row['median_ms']:10.1f} {row['max_ms']:8.1f} {row['cold_ms']:8.1f} {row['kb']:8.0f}")
    worst = max(rows, key=lambda row: row["median_ms"])
    ok = worst["median_ms"] <= args.limit_ms
    print(
        f"\nslowest: {worst['page']} {worst['median_ms']:.1f} ms -> {'OK' if ok else 'FAIL'}",
        f"(limit {args.limit_ms:.0f} ms)",
    )
    if args.json:
        args.json.write_text(json.dumps({"size": [width, height], "repeats": args.repeats, "pages": rows}, indent=2))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
