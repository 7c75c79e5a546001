from django.contrib import admin

from metrology.inspections.models import Inspection, InspectionPlan, NominalModel

admin.site.register(NominalModel)
admin.site.register(Inspection)
admin.site.register(InspectionPlan)
