from __future__ import annotations

from django.apps import AppConfig


class InspectionsConfig(AppConfig):
    name = "metrology.inspections"
    label = "inspections"

    def ready(self) -> None:
        from metrology.jobs.handlers import register_handler
        from metrology.jobs.models import Job
        from metrology.measurements.signals import measurement_done

        register_handler(Job.Kind.INSPECTION, "metrology.inspections.services.run_inspection")
        measurement_done.connect(_apply_plan, dispatch_uid="inspections.apply_plan")


def _apply_plan(sender, measurement, **_kwargs) -> None:
    """A finished measurement: queue the inspection its rig's plan asks for."""
    import logging

    from metrology.inspections.services import apply_plan

    try:
        apply_plan(measurement)
    except Exception:  # the measurement is published; a plan that cannot run must not undo it
        logging.getLogger(__name__).exception("the inspection plan of rig %s could not start", measurement.rig_id)
