"""Reads for nominal models, inspections and inspection plans, scoped to the user."""

from __future__ import annotations

from django.db.models import QuerySet
from django.http import Http404

from metrology.inspections.models import Inspection, InspectionPlan, NominalModel


def nominals_for(user) -> QuerySet[NominalModel]:
    return NominalModel.objects.filter(owner=user)


def get_nominal(user, nominal_id) -> NominalModel:
    found = nominals_for(user).filter(pk=nominal_id).first() if str(nominal_id).isdigit() else None
    if found is None:
        raise Http404(f"No nominal model {nominal_id} among yours.")
    return found


def inspections_for(user) -> QuerySet[Inspection]:
    return Inspection.objects.filter(owner=user).select_related("job", "nominal", "measurement", "measurement__rig")


def get_inspection(user, inspection_id) -> Inspection:
    found = inspections_for(user).filter(pk=inspection_id).first() if str(inspection_id).isdigit() else None
    if found is None:
        raise Http404(f"No inspection {inspection_id} among yours.")
    return found


def inspections_of_measurement(measurement) -> QuerySet[Inspection]:
    return Inspection.objects.filter(measurement=measurement).select_related("job", "nominal")


def plan_of_rig(rig) -> InspectionPlan | None:
    return InspectionPlan.objects.filter(rig=rig).select_related("nominal").first()


def plan_inspections(plan: InspectionPlan) -> QuerySet[Inspection]:
    """The finished inspections a plan made, oldest first (the trend across measurements)."""
    return (
        Inspection.objects.filter(plan=plan, job__status="done")
        .select_related("job", "measurement")
        .order_by("created_at", "id")
    )
