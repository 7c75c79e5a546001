"""Forms of the pages: they parse and check what a person typed; the services decide the rest."""

from __future__ import annotations

import json
from typing import Any

from django import forms

from metrology.captures.models import Capture
from metrology.captures.simulation import PRESETS
from metrology.core.io.step import LINEAR_TOLERANCE_MM
from metrology.dashboard.selectors import capture_origin
from metrology.jobs.models import Job

# Which scene parameter the "Z" field of the simulate form sets (scenes without one ignore it).
SCENE_Z_PARAMETER = {"plane": "z_mm", "block": "top_mm", "stage": "z_in_mm", "staircase": "step_height_mm"}
SCENE_CHOICES = [
    ("reference", "reference plane (Z = 0)"),
    ("plane", "plane at height Z"),
    ("block", "master block, top at Z"),
    ("sphere", "sphere"),
    ("two_spheres", "two spheres (ball bar)"),
    ("staircase", "staircase, steps of Z"),
    ("face", "face"),
    ("flowerpot", "flowerpot"),
    ("stage", "stage plane at Z_in = Z"),
]
NOISE_PRESETS: dict[str, tuple[str, dict]] = {
    "none": ("noise free, 16 bit", {"bit_depth": 16}),
    "low": ("low noise, 8 bit (0.5 grey levels)", {"bit_depth": 8, "noise_grey": 0.5}),
    "demo": ("realistic, 8 bit (1.5 grey levels, slight blur; the API's default)", PRESETS["realistic"]),
    "high": ("noisy, 8 bit (4 grey levels, blur)", {"bit_depth": 8, "noise_grey": 4.0, "camera_defocus_px": 0.8}),
}
DEFAULT_ROLE_FOR_SCENE = {"reference": "reference", "block": "master", "stage": "stage"}


class JobFilterForm(forms.Form):
    """The filters of the jobs page: a kind and a state, each optional (GET parameters)."""

    kind = forms.ChoiceField(required=False, choices=[("", "every kind"), *Job.Kind.choices])
    status = forms.ChoiceField(required=False, label="State", choices=[("", "every state"), *Job.Status.choices])

    def filters(self) -> dict[str, str]:
        """``{"kind": ..., "status": ...}`` for :func:`metrology.jobs.selectors.jobs_filtered` (empty: no filter)."""
        data = self.cleaned_data if self.is_valid() else {}
        return {"kind": data.get("kind", ""), "status": data.get("status", "")}


class RigForm(forms.Form):
    """A rig typed value by value: one field per scalar parameter of a model
    (:attr:`~metrology.core.geometry.base.GeometryModel.scalar_parameters`; the default model
    unless told), its :meth:`~metrology.core.geometry.base.GeometryModel.example_parameters` as
    initial values."""

    name = forms.CharField(max_length=200, required=False, help_text="A name you will recognise")
    notes = forms.CharField(widget=forms.Textarea(attrs={"rows": 2}), required=False)

    def __init__(self, *args: Any, model_name: str | None = None, **kwargs: Any) -> None:
        from metrology.core.geometry import MODELS
        from metrology.rigs.models import DEFAULT_MODEL

        super().__init__(*args, **kwargs)
        self.model_name = model_name or DEFAULT_MODEL
        model = MODELS[self.model_name]
        initial = model.example_parameters()
        fields: dict[str, forms.Field] = {"name": self.fields.pop("name")}
        for spec in model.scalar_parameters:
            label = f"{spec.name} ({spec.unit})" if spec.unit else spec.name
            field: forms.Field
            start = initial.get(spec.name)
            if spec.integer:
                field = forms.IntegerField(label=label, initial=start, help_text=spec.label, min_value=1)
            else:
                field = forms.FloatField(label=label, initial=start, help_text=spec.label)
            fields[spec.name] = field
        fields["notes"] = self.fields.pop("notes")
        self.fields = fields

    def rig_data(self) -> dict[str, Any]:
        """The rig file of the typed values (for :func:`metrology.rigs.services.create_rig`)."""
        return {"model": self.model_name, **self.cleaned_data}


def _json_upload(upload: Any, what: str) -> Any:
    import json

    from django.conf import settings

    if upload.size is not None and upload.size > settings.GCPS_MAX_RIG_FILE_BYTES:
        raise forms.ValidationError(f"a {what} is at most {settings.GCPS_MAX_RIG_FILE_BYTES} bytes")
    from metrology.json_input import load_json_text

    try:
        data = load_json_text(upload.read().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise forms.ValidationError(f"not a JSON {what}: {exc}") from None
    except ValueError as exc:
        raise forms.ValidationError(f"{what} refused: {exc}") from None
    if not isinstance(data, dict):
        raise forms.ValidationError(f"the {what} must be a JSON object")
    return data


class RigFileForm(forms.Form):
    """A rig file of any model (docs/file-formats.md; ``gcps rig import`` writes pinhole ones)."""

    name = forms.CharField(max_length=200, required=False, help_text="A name you will recognise")
    rig_file = forms.FileField(
        label="Rig file (.json)",
        help_text="Any model's rig file: the seven crossed-axes values, or a file with a model key (docs/pinhole.md)",
    )

    def clean_rig_file(self) -> Any:
        return _json_upload(self.cleaned_data["rig_file"], "rig file")


class CalibrationFileForm(forms.Form):
    """An OpenCV FileStorage calibration file (YAML/XML), read as ``gcps rig import --opencv`` reads it."""

    calibration_file = forms.FileField(
        label="Calibration file (.yml, .yaml, .xml)",
        help_text="OpenCV FileStorage: camera and projector matrices, distortion, R and T, found by their node names",
    )
    projector_width = forms.FloatField(min_value=1, label="projector width", help_text="In the codec's units")
    projector_height = forms.FloatField(min_value=1, label="projector height")
    camera_width_px = forms.IntegerField(
        min_value=1, required=False, label="camera width (px)", help_text="When the file gives no image size"
    )
    camera_height_px = forms.IntegerField(min_value=1, required=False, label="camera height (px)")

    def clean(self) -> dict[str, Any]:
        data = super().clean() or {}
        given = [data.get("camera_width_px") is not None, data.get("camera_height_px") is not None]
        if any(given) and not all(given):
            raise forms.ValidationError("Give both camera width and height, or neither (the file's size node).")
        return data

    def import_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :func:`metrology.rigs.services.read_calibration_upload` and the
        imports built on it (upload and sizes)."""
        data = self.cleaned_data
        camera = None
        if data.get("camera_width_px") is not None:
            camera = (data["camera_width_px"], data["camera_height_px"])
        return {
            "upload": data["calibration_file"],
            "projector_size": (data["projector_width"], data["projector_height"]),
            "camera_size": camera,
        }


class CalibrationImportForm(CalibrationFileForm):
    """A calibration file that becomes a new rig (the Rigs page), with the rig's name."""

    name = forms.CharField(max_length=200, required=False, help_text="A name you will recognise")
    field_order = ["name", "calibration_file", "projector_width", "projector_height"]  # noqa: RUF012 (Django reads it as a class attribute)

    def import_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :func:`metrology.rigs.services.import_calibration_file` (without owner)."""
        return {**super().import_kwargs(), "name": self.cleaned_data.get("name") or ""}


class RigCodecForm(forms.Form):
    codec = forms.CharField(
        label="Default codec",
        widget=forms.Textarea(attrs={"rows": 6, "spellcheck": "false"}),
        max_length=200_000,
        help_text=(
            "A built-in name (gcps-v1, gcps-v1:1280x800) or a gcps-codec/1 codec file's JSON (docs/codecs.md); "
            "used for uploads that carry no codec.json"
        ),
    )

    def clean_codec(self):
        import json

        from metrology.json_input import load_json_text

        text = self.cleaned_data["codec"].strip()
        if text.startswith("{"):
            try:
                return load_json_text(text)
            except json.JSONDecodeError as exc:
                raise forms.ValidationError(f"not valid JSON: {exc.msg} at line {exc.lineno}") from None
            except ValueError as exc:
                raise forms.ValidationError(f"codec refused: {exc}") from None
        return text


class UploadCaptureForm(forms.Form):
    file = forms.FileField(
        label="Stack (.zip)",
        help_text="A zip of GC_0..GC_6 and PS_0..PS_3 images, or of any codec's frames with its codec.json",
    )
    role = forms.ChoiceField(choices=Capture.Role.choices, initial=Capture.Role.OBJECT)
    z_in_mm = forms.FloatField(label="Z_in (mm)", required=False, help_text="Stage position (stage captures only)")
    repeat = forms.IntegerField(min_value=0, initial=0, required=False)


class SimulateCaptureForm(forms.Form):
    scene = forms.ChoiceField(choices=SCENE_CHOICES, initial="plane")
    z_mm = forms.FloatField(
        label="Z (mm)", required=False, initial=20.0, help_text="Plane height, block top, stage Z_in or step height"
    )
    noise = forms.ChoiceField(
        label="Noise", choices=[(key, label) for key, (label, _) in NOISE_PRESETS.items()], initial="demo"
    )
    role = forms.ChoiceField(
        choices=[("", "from the scene"), *Capture.Role.choices], required=False, help_text="Default: from the scene"
    )
    seed = forms.IntegerField(min_value=0, initial=0, required=False)

    def request_kwargs(self) -> dict:
        """Keyword arguments of ``request_simulated_capture`` (without owner and rig)."""
        data = self.cleaned_data
        name = data["scene"]
        scene: dict = {"name": name}
        z = data.get("z_mm")
        parameter = SCENE_Z_PARAMETER.get(name)
        if parameter and z is not None:
            scene[parameter] = z
        role = data.get("role") or DEFAULT_ROLE_FOR_SCENE.get(name, "object")
        options = {**NOISE_PRESETS[data["noise"]][1], "seed": data.get("seed") or 0}
        z_in = z if name == "stage" else None
        if name == "stage":
            scene.pop("z_in_mm", None)  # taken from the capture's z_in_mm
        return {"role": role, "scene": scene, "options": options, "z_in_mm": z_in}


class StageSeriesForm(forms.Form):
    z_from_mm = forms.FloatField(label="from Z_in (mm)", initial=0.0)
    z_to_mm = forms.FloatField(label="to Z_in (mm)", initial=8.0)
    z_step_mm = forms.FloatField(label="step (mm)", initial=4.0, min_value=0.001)
    repeats = forms.IntegerField(min_value=1, max_value=30, initial=2)
    noise = forms.ChoiceField(choices=[(key, label) for key, (label, _) in NOISE_PRESETS.items()], initial="demo")

    MAX_CAPTURES = 400

    def clean(self) -> dict[str, Any]:
        from metrology.core.simulate import stage_positions

        super().clean()
        data = self.cleaned_data
        lo, hi, step = data.get("z_from_mm"), data.get("z_to_mm"), data.get("z_step_mm")
        if lo is not None and hi is not None and step is not None:
            if hi <= lo:
                raise forms.ValidationError("'to Z_in' must be above 'from Z_in'.")
            positions = stage_positions(lo, hi, step)
            count = len(positions)
            if count < 2:
                raise forms.ValidationError("The series needs at least two stage positions: reduce the step.")
            if count * (data.get("repeats") or 1) > self.MAX_CAPTURES:
                raise forms.ValidationError(f"That makes more than {self.MAX_CAPTURES} captures: widen the step.")
            data["positions"] = positions
        return data


def capture_choices(captures, empty: str = "choose a capture") -> list[tuple[str, str]]:
    def label(capture: Capture) -> str:
        origin = capture_origin(capture)
        z = f", Z_in {capture.z_in_mm:g} mm" if capture.z_in_mm is not None else ""
        return f"#{capture.pk} {capture.role} ({origin}{z})"

    return [("", empty)] + [(str(c.pk), label(c)) for c in captures]


def set_choices(form: forms.Form, name: str, choices: list[tuple[str, str]]) -> None:
    """Set the choices of the form's choice field ``name`` (declared as a ChoiceField by the form)."""
    field = form.fields[name]
    assert isinstance(field, forms.ChoiceField), f"{name} is not a choice field"
    field.choices = choices


class MeasurementForm(forms.Form):
    fields: dict[str, Any]  # choice fields, set up per instance below (BaseForm types them as Field: no choices)
    reference = forms.TypedChoiceField(coerce=int, label="Reference capture")
    object = forms.TypedChoiceField(coerce=int, label="Object capture")
    sigma = forms.BooleanField(
        required=False,
        label="Per-point uncertainty",
        help_text="Also compute each point's standard uncertainty (mm) from the object's phase noise",
    )
    allow_inconsistent_codec = forms.BooleanField(
        required=False,
        label="Measure even if the codec self-check fails",
        help_text="A capture inconsistent with its codec (see the capture's page) is otherwise refused",
    )

    def options(self) -> dict[str, Any] | None:
        """The measurement options the form sets (None: the defaults)."""
        data = self.cleaned_data
        chosen = {key: True for key in ("sigma", "allow_inconsistent_codec") if data.get(key)}
        return chosen or None

    def __init__(self, *args, captures=(), reference_optional: bool = False, unreferenced: str = "depth", **kwargs):
        super().__init__(*args, **kwargs)
        captures = list(captures)
        self.fields["reference"].choices = capture_choices([c for c in captures if c.role == "reference"])
        self.fields["object"].choices = capture_choices([c for c in captures if c.role != "reference"])
        if reference_optional:  # the rig's model measures without a reference: depths
            self.fields["reference"].required = False
            self.fields["reference"].choices = capture_choices(
                [c for c in captures if c.role == "reference"], empty=f"none: {unreferenced}s (camera Z)"
            )
            self.fields["reference"].empty_value = None


class CalibrationForm(forms.Form):
    reference = forms.TypedChoiceField(coerce=int, label="Reference capture")
    master = forms.TypedChoiceField(coerce=int, label="Master capture")
    master_height_mm = forms.FloatField(label="Master height H (mm)", initial=40.0)
    method = forms.ChoiceField(choices=[("lsq", "least squares"), ("paper", "paper (iterative, section 4)")])
    initial_L_mm = forms.FloatField(label="Start L (mm)", required=False, help_text="Default: the rig's value")
    initial_alpha_rad = forms.FloatField(label="Start alpha (rad)", required=False, help_text="Default: the rig's")
    apply = forms.BooleanField(required=False, label="Apply the result to the rig when done")

    def __init__(self, *args, captures=(), **kwargs):
        super().__init__(*args, **kwargs)
        captures = list(captures)
        set_choices(self, "reference", capture_choices([c for c in captures if c.role == "reference"]))
        set_choices(self, "master", capture_choices([c for c in captures if c.role in ("master", "object")]))

    def initial_values(self) -> dict:
        data = self.cleaned_data
        out = {}
        if data.get("initial_L_mm") is not None:
            out["L_mm"] = data["initial_L_mm"]
        if data.get("initial_alpha_rad") is not None:
            out["alpha_rad"] = data["initial_alpha_rad"]
        return out


class CharacterizationForm(forms.Form):
    reference = forms.TypedChoiceField(coerce=int, label="Reference capture")
    session = forms.TypedChoiceField(coerce=int, label="Stage session", help_text="Its stage captures form the series")
    n_points = forms.IntegerField(label="Test points per row", initial=21, min_value=2, max_value=1000)
    rows = forms.IntegerField(label="Rows of test points", initial=1, min_value=1, max_value=50)

    def __init__(self, *args, captures=(), sessions=(), **kwargs):
        super().__init__(*args, **kwargs)
        set_choices(self, "reference", capture_choices([c for c in captures if c.role == "reference"]))
        set_choices(
            self,
            "session",
            [("", "choose a session")]
            + [(str(s.pk), f"#{s.pk} {s.name or 'session'} ({s.n_stage} stage captures)") for s in sessions],
        )


class MultipleFileInput(forms.ClearableFileInput):
    """A file input that takes several files (``<input type=file multiple>``)."""

    allow_multiple_selected = True


class MultipleFileField(forms.FileField):
    """Several uploaded files: a list (empty when none and not required)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("widget", MultipleFileInput(attrs={"accept": ".zip,application/zip"}))
        super().__init__(*args, **kwargs)

    def clean(self, data: Any, initial: Any = None) -> Any:
        files = [item for item in (data if isinstance(data, list | tuple) else [data]) if item]
        if not files:
            if self.required:
                raise forms.ValidationError(self.error_messages["required"], code="required")
            return []
        return [super(MultipleFileField, self).clean(item, initial) for item in files]


BOARD_HELP = (
    "KIND:COLSxROWS:SIZE_MM. COLSxROWS is OpenCV's pattern size: the inner corners of a chessboard (where "
    "four squares meet), points per row first; a board of 10 x 8 squares of 25 mm is chessboard:9x7:25. "
    "circles:COLSxROWS:SPACING_MM and acircles:... for circle grids."
)


def _grey_levels_field(label: str, help_text: str) -> forms.FloatField:
    """An optional decoder threshold in grey levels of the stack (empty: the decoder's default)."""
    return forms.FloatField(
        label=label,
        required=False,
        min_value=0.0,
        max_value=65535.0,
        help_text=f"{help_text}; empty: 4 at 8 bits (1028 at 16 bits)",
    )


class ProcamCalibrationForm(forms.Form):
    fields: dict[str, Any]
    board = forms.CharField(max_length=100, initial="chessboard:9x7:25", help_text=BOARD_HELP)
    pose_files = MultipleFileField(
        label="Pose stacks (.zip, one per pose)",
        required=False,
        help_text=(
            "Select several files: one zip per board pose, each the frames of a codec coding both projector axes "
            "with its codec.json (docs/codecs.md). They are stored as board captures in one new capture session."
        ),
    )
    existing = forms.TypedMultipleChoiceField(
        coerce=int,
        required=False,
        label="Board captures already stored",
        widget=forms.CheckboxSelectMultiple,
        help_text="Used after the uploaded poses, in this order",
    )
    window = forms.IntegerField(
        label="Corner window (px)",
        required=False,
        min_value=1,
        max_value=200,
        help_text="Half-size of each corner's homography window; empty: half the corner spacing, 4 to 30 px",
    )
    min_decoded = forms.FloatField(
        label="Decoded fraction a corner needs",
        initial=0.25,
        min_value=0.0,
        max_value=1.0,
        help_text="A corner is used when this fraction of its window is decoded",
    )
    min_modulation = _grey_levels_field(
        "Smallest fringe modulation (grey levels)", "Pixels with a weaker fringe amplitude are not decoded"
    )
    min_inverse_contrast = _grey_levels_field(
        "Smallest gray-code contrast to its inverse (grey levels)", "For codecs with inverse frames"
    )
    fix_k3 = forms.BooleanField(required=False, label="Hold k3 at 0 (few poses, mild distortion)")
    fixed_intrinsics = forms.BooleanField(
        required=False,
        label="Keep each device's own intrinsics in the stereo fit",
        help_text="Default: refine both devices' intrinsics jointly with their pose (predicts unseen poses better)",
    )
    apply = forms.BooleanField(required=False, label="Make the result the rig's calibration when done")

    def __init__(self, *args: Any, board_captures: Any = (), **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        set_choices(self, "existing", capture_choices(list(board_captures))[1:])

    def clean(self) -> dict[str, Any]:
        data = super().clean() or {}
        count = len(data.get("pose_files") or []) + len(data.get("existing") or [])
        if not self.errors and count < 2:
            raise forms.ValidationError("Give at least two poses (8 to 12 recommended): upload zips or pick captures.")
        return data

    def options(self) -> dict[str, Any]:
        """The request's options (``window`` and the decoder thresholds only when given)."""
        data = self.cleaned_data
        options: dict[str, Any] = {
            "min_decoded": data["min_decoded"],
            "fix_k3": data["fix_k3"],
            "joint": not data["fixed_intrinsics"],
        }
        for name in ("window", "min_modulation", "min_inverse_contrast"):
            if data.get(name) is not None:
                options[name] = data[name]
        return options


class NominalUploadForm(forms.Form):
    file = forms.FileField(
        label="Nominal model",
        help_text=(
            "A triangle mesh in millimetres (binary or ASCII STL, PLY or OBJ, faces oriented outwards) "
            f"or a STEP file (.step, .stp), tessellated to {LINEAR_TOLERANCE_MM} mm"
        ),
        widget=forms.ClearableFileInput(attrs={"accept": ".stl,.ply,.obj,.step,.stp"}),
    )
    name = forms.CharField(label="Name", required=False, max_length=200, help_text="Default: the file's name")


INIT_CHOICES = [
    ("auto", "automatic (global registration, several starts)"),
    ("identity", "identity (the measurement is already roughly aligned)"),
]


class InspectionForm(forms.Form):
    """The options of an inspection (or of a rig's inspection plan) as a person types them."""

    nominal = forms.TypedChoiceField(coerce=int, label="Nominal model")
    init = forms.ChoiceField(label="Alignment start", choices=INIT_CHOICES, initial="auto")
    tolerance_mm = forms.FloatField(
        label="Tolerance (mm)",
        required=False,
        min_value=0.0,
        help_text="Allowed |deviation|; empty: no conformance decision",
    )
    k = forms.FloatField(label="Coverage factor k", initial=2.0, min_value=0.0, max_value=10.0)
    systematic_mm = forms.FloatField(
        label="Systematic term (mm)",
        required=False,
        min_value=0.0,
        help_text="Empty: the rig's latest characterization (its mean error), or 0 without one",
    )
    features = forms.CharField(
        label="Features (JSON)",
        required=False,
        widget=forms.Textarea(attrs={"rows": 4, "spellcheck": "false"}),
        help_text='A JSON list of {"name", "kind": plane|sphere|cylinder|circle, "region": {"box_mm": '
        '[[x0, y0, z0], [x1, y1, z1]], "near_faces": [...], "within_mm": d}} in the nominal\'s frame '
        "(docs/inspection.md); empty: none",
    )

    def __init__(self, *args, nominals=(), **kwargs):
        initial = kwargs.get("initial")
        if initial and isinstance(initial.get("features"), list):  # a plan's stored features, shown as JSON
            kwargs["initial"] = {**initial, "features": json.dumps(initial["features"]) if initial["features"] else ""}
        super().__init__(*args, **kwargs)
        set_choices(
            self,
            "nominal",
            [("", "choose a nominal model")]
            + [(str(n.pk), f"#{n.pk} {n.name} ({n.triangle_count} triangles)") for n in nominals],
        )

    def clean_features(self) -> list[dict[str, Any]]:
        """The features typed as JSON, validated (:func:`~metrology.core.inspection.feature_regions.parse_features`)."""
        from metrology.core.inspection.feature_regions import parse_features

        text = (self.cleaned_data.get("features") or "").strip()
        if not text:
            return []
        try:
            return [spec.to_dict() for spec in parse_features(json.loads(text))]
        except json.JSONDecodeError as exc:
            raise forms.ValidationError(f"Not valid JSON: {exc.msg} (line {exc.lineno}, column {exc.colno}).") from None
        except ValueError as exc:
            raise forms.ValidationError(str(exc)) from None

    def options(self) -> dict[str, Any]:
        """The inspection options the form gives (those left empty are not set)."""
        data = self.cleaned_data
        options: dict[str, Any] = {"init": data["init"], "k": data["k"]}
        for name in ("tolerance_mm", "systematic_mm"):
            if data.get(name) is not None:
                options[name] = data[name]
        if data.get("features"):
            options["features"] = data["features"]
        return options
