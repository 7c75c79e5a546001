"""Inspection against a nominal model (docs/inspection.md): numpy and Open3D only, no Django.

Modules:

- :mod:`.nominal`: the nominal triangle mesh (STL, PLY, OBJ, or a tessellated STEP solid), validated, in mm;
- :mod:`.scan`: the scan's points in input order, their sigma and how it is meant;
- :mod:`.distance`: signed distances to the surface, sign by angle-weighted pseudo-normals;
- :mod:`.alignment`: starts (global registration, point pairs, 3-2-1 datums) and the weighted,
  trimmed point-to-plane best fit with its covariance and free degrees of freedom;
- :mod:`.conformance`: each point's uncertainty along the normal and the ISO 14253-1 decision;
- :mod:`.features`: feature fits (planes, spheres, cylinders, circles) and form errors.

The use case from files to a report is :func:`metrology.pipeline.inspect.inspect`.
"""
