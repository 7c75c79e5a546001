"""Django settings for GCPS Lab, read from the environment (see README.md, "Running on PostgreSQL").

With nothing set the app runs on the embedded default: SQLite and media under ``./var/``, Celery
tasks executed in-process. ``DATABASE_URL`` and ``REDIS_URL`` (or ``CELERY_BROKER_URL``) switch to
PostgreSQL and a Redis broker with separate ``celery -A workers worker`` processes.

Every variable goes through a small strict parser that raises ``ImproperlyConfigured`` naming
the variable, so a typo fails at start-up instead of at the first request.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import dj_database_url
from django.core.exceptions import ImproperlyConfigured

BASE_DIR = Path(__file__).resolve().parent.parent

_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off", ""}


def env_bool(name: str, default: bool) -> bool:
    raw = os.environ.get(name)
    if raw is None:
        return default
    value = raw.strip().lower()
    if value in _TRUE:
        return True
    if value in _FALSE:
        return False
    raise ImproperlyConfigured(f"{name} must be one of 1/0, true/false, yes/no, on/off; got {raw!r}")


def env_int(name: str, default: int, *, minimum: int | None = None) -> int:
    raw = os.environ.get(name)
    if raw is None or raw.strip() == "":
        return default
    try:
        value = int(raw.strip())
    except ValueError:
        raise ImproperlyConfigured(f"{name} must be an integer, got {raw!r}") from None
    if minimum is not None and value < minimum:
        raise ImproperlyConfigured(f"{name} must be at least {minimum}, got {value}")
    return value


def env_float(name: str, default: float, *, minimum: float | None = None) -> float:
    raw = os.environ.get(name)
    if raw is None or raw.strip() == "":
        return default
    try:
        value = float(raw.strip())
    except ValueError:
        raise ImproperlyConfigured(f"{name} must be a number, got {raw!r}") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise ImproperlyConfigured(f"{name} must be a finite number, got {raw!r}")
    if minimum is not None and value < minimum:
        raise ImproperlyConfigured(f"{name} must be at least {minimum}, got {value}")
    return value


def env_str(name: str, default: str = "") -> str:
    return os.environ.get(name, default).strip()


def env_list(name: str, default: list[str]) -> list[str]:
    raw = os.environ.get(name)
    if raw is None:
        return default
    items = [item.strip() for item in raw.split(",") if item.strip()]
    if not items:
        raise ImproperlyConfigured(f"{name} must be a comma-separated list, got {raw!r}")
    return items


def env_rate(name: str, default: str) -> str | None:
    """A rate ``N/period`` (period second, minute, hour or day, or their first letter); ``off`` for none."""
    raw = env_str(name, default)
    if raw.lower() in ("off", "none"):
        return None
    count, _, period = raw.partition("/")
    if not count.strip().isdigit() or int(count) < 1 or period.strip().lower() not in _RATE_PERIODS:
        raise ImproperlyConfigured(f"{name} must look like 100/minute (second, minute, hour, day) or off, got {raw!r}")
    return raw


_RATE_PERIODS = {"s", "sec", "second", "m", "min", "minute", "h", "hour", "d", "day"}


def env_url(name: str, schemes: tuple[str, ...]) -> str:
    raw = os.environ.get(name, "").strip()
    if raw and not raw.startswith(tuple(f"{scheme}://" for scheme in schemes)):
        raise ImproperlyConfigured(f"{name} must start with one of {', '.join(schemes)}://, got {raw!r}")
    return raw


# The embedded default: no database and no broker configured. It runs with DEBUG on (a local
# development instance); as soon as DATABASE_URL or a broker is set, DEBUG defaults to off.
EMBEDDED = not (os.environ.get("DATABASE_URL") or os.environ.get("REDIS_URL") or os.environ.get("CELERY_BROKER_URL"))
DEBUG = env_bool("DEBUG", EMBEDDED)

SECRET_KEY = env_str("SECRET_KEY")
if not SECRET_KEY:
    if not DEBUG:
        raise ImproperlyConfigured("SECRET_KEY must be set when DEBUG is off (50+ random characters)")
    SECRET_KEY = "dev-only-gcps-lab-secret-key-change-me-3f8a9c1e7b2d4f6a8c0e1b3d5f7a9c1e"
elif not DEBUG and len(SECRET_KEY) < 50:
    raise ImproperlyConfigured("SECRET_KEY must be at least 50 characters long")

ALLOWED_HOSTS = env_list("ALLOWED_HOSTS", ["localhost", "127.0.0.1", "[::1]"])
CSRF_TRUSTED_ORIGINS = env_list("CSRF_TRUSTED_ORIGINS", [])

INSTALLED_APPS = [
    "django.contrib.admin",
    "django.contrib.auth",
    "django.contrib.contenttypes",
    "django.contrib.sessions",
    "django.contrib.messages",
    "django.contrib.staticfiles",
    "rest_framework",
    "rest_framework.authtoken",
    "drf_spectacular",
    "drf_spectacular_sidecar",
    "django_celery_beat",
    "metrology.accounts",
    "metrology.jobs",
    "metrology.rigs",
    "metrology.captures",
    "metrology.measurements",
    "metrology.calibrations",
    "metrology.characterizations",
    "metrology.inspections",
    "metrology.reports",
    "metrology.acquisition",
    "metrology.dashboard",
]

MIDDLEWARE = [
    # under ASGI, streamed files are sent as they are read (Django would read them whole first)
    "metrology.streaming.AsyncStreamingMiddleware",
    "django.middleware.security.SecurityMiddleware",
    "metrology.security_headers.ContentSecurityPolicyMiddleware",
    "metrology.api_input.RequestBodyLimitMiddleware",
    "metrology.throttling.LoginThrottleMiddleware",
    "whitenoise.middleware.WhiteNoiseMiddleware",
    # a request whose database connection broke is retried once; 503 (not 500) when it stays down
    "metrology.unavailable.TransientErrorMiddleware",
    "django.contrib.sessions.middleware.SessionMiddleware",
    "django.middleware.common.CommonMiddleware",
    "django.middleware.csrf.CsrfViewMiddleware",
    "django.contrib.auth.middleware.AuthenticationMiddleware",
    "django.contrib.messages.middleware.MessageMiddleware",
    "django.middleware.clickjacking.XFrameOptionsMiddleware",
]

ROOT_URLCONF = "metrology.urls"
WSGI_APPLICATION = "metrology.wsgi.application"
ASGI_APPLICATION = "metrology.asgi.application"

TEMPLATES = [
    {
        "BACKEND": "django.template.backends.django.DjangoTemplates",
        "DIRS": [BASE_DIR / "templates"],
        "APP_DIRS": True,
        "OPTIONS": {
            "context_processors": [
                "django.template.context_processors.request",
                "django.contrib.auth.context_processors.auth",
                "django.contrib.messages.context_processors.messages",
            ],
        },
    },
]

# ----------------------------------------------------------------------------- storage
VAR_DIR = Path(env_str("GCPS_VAR_DIR") or BASE_DIR / "var")
MEDIA_ROOT = Path(env_str("MEDIA_ROOT") or VAR_DIR / "media")
MEDIA_URL = "/media/"
STATIC_ROOT = Path(env_str("STATIC_ROOT") or VAR_DIR / "static")
STATIC_URL = "/static/"
# Static files (admin, the offline Swagger UI) are served by WhiteNoise from STATIC_ROOT after
# ``manage.py collectstatic``, and straight from the apps when DEBUG is on.
# Results, captures, derived files and reports go through Django's storage API only (never a
# local path): the local MEDIA_ROOT by default, or an S3-compatible bucket when GCPS_S3_BUCKET is
# set (docs/storage.md). Files stay private; downloads are served by the app, by the reverse proxy
# (GCPS_ACCEL_REDIRECT, local storage) or from short-lived presigned URLs (S3).
GCPS_S3_BUCKET = env_str("GCPS_S3_BUCKET")
_default_storage: dict[str, Any] = {"BACKEND": "django.core.files.storage.FileSystemStorage"}
if GCPS_S3_BUCKET:
    _default_storage = {
        "BACKEND": "storages.backends.s3.S3Storage",
        "OPTIONS": {
            "bucket_name": GCPS_S3_BUCKET,
            "endpoint_url": env_str("GCPS_S3_ENDPOINT_URL") or None,
            "access_key": env_str("GCPS_S3_ACCESS_KEY_ID") or None,
            "secret_key": env_str("GCPS_S3_SECRET_ACCESS_KEY") or None,
            "region_name": env_str("GCPS_S3_REGION", "us-east-1"),
            "default_acl": None,  # private: the bucket's policy, never a public ACL
            "querystring_auth": True,
            "querystring_expire": env_int("GCPS_S3_URL_SECONDS", 300, minimum=1),  # see below
            "file_overwrite": True,
            "signature_version": "s3v4",
            "addressing_style": "path",
        },
    }
STORAGES = {
    "default": _default_storage,
    "staticfiles": {"BACKEND": "whitenoise.storage.CompressedStaticFilesStorage"},
}
# With local storage behind the documented nginx (deploy/nginx/gcps.conf): answer downloads with
# X-Accel-Redirect: /protected/<storage name> and let nginx send the file (ranges, slow clients).
GCPS_ACCEL_REDIRECT = env_bool("GCPS_ACCEL_REDIRECT", False)
# How long a presigned S3 download URL stays valid, seconds.
GCPS_S3_URL_SECONDS = env_int("GCPS_S3_URL_SECONDS", 300, minimum=1)
WHITENOISE_USE_FINDERS = DEBUG
# In development (DEBUG) WhiteNoise looks a static file up when it is asked for rather than listing
# every app's static files when the middleware is built: the listing (about 20 ms of CPU) was paid
# by every Django test client and every development server process, for files mostly never asked for.
WHITENOISE_AUTOREFRESH = DEBUG
with contextlib.suppress(OSError):  # WhiteNoise warns on every request while the folder is missing
    STATIC_ROOT.mkdir(parents=True, exist_ok=True)

# ----------------------------------------------------------------------------- database
_database_url = env_url("DATABASE_URL", ("postgres", "postgresql", "pgsql", "sqlite"))
# read-only here: dj_database_url's typed configuration or the sqlite one below (whose NAME is a Path)
DATABASES: dict[str, Mapping[str, Any]]
# connections are kept 60 s for the next request of their thread, on either database
# (GCPS_DB_CONN_MAX_AGE; the ASGI entry point sets 0: its requests run in threads of their own, so a
# kept connection would never be reused)
_conn_max_age = env_int("GCPS_DB_CONN_MAX_AGE", 60, minimum=0)
if _database_url:
    try:
        # checked before reuse (one killed while idle is reopened); GCPS_DB_HEALTH_CHECKS=0 leaves
        # only the in-request retry (metrology/unavailable.py)
        DATABASES = {
            "default": dj_database_url.parse(
                _database_url,
                conn_max_age=_conn_max_age,
                conn_health_checks=env_bool("GCPS_DB_HEALTH_CHECKS", True),
            )
        }
    except ValueError as exc:
        raise ImproperlyConfigured(f"DATABASE_URL is not a valid database URL: {exc}") from None
else:
    VAR_DIR.mkdir(parents=True, exist_ok=True)
    DATABASES = {
        "default": {
            "ENGINE": "django.db.backends.sqlite3",
            "NAME": VAR_DIR / "gcps.sqlite3",
            # writers wait for each other (timeout, s) and take the write lock as their transaction
            # begins (IMMEDIATE), so that two of them (a request and the embedded job thread) never
            # deadlock on upgrading a read lock; WAL lets pages read while a job writes.
            # synchronous=NORMAL, SQLite's advice for WAL: the log is synced at checkpoints, not at
            # every commit (2.8 ms per commit -> 0.03 ms on the reference VM); the database stays
            # consistent, and only a power loss or OS crash (not a killed process) may undo the
            # last commits (docs/operations.md).
            # Opening a connection costs about 1 ms of CPU (Django's set-up of the connection,
            # SQLite's reading of the schema at its first statement): kept as with DATABASE_URL.
            "CONN_MAX_AGE": _conn_max_age,
            "OPTIONS": {
                "timeout": 20,
                "transaction_mode": "IMMEDIATE",
                "init_command": "PRAGMA journal_mode=WAL; PRAGMA synchronous=NORMAL;",
            },
            # tests get a file, not Django's shared in-memory database: the live server, the
            # test and in-process job threads then each have their own connection, and
            # concurrent writers wait (timeout) instead of failing with "table is locked"
            "TEST": {"NAME": VAR_DIR / f"test-{os.getpid()}.sqlite3"},
        }
    }
DEFAULT_AUTO_FIELD = "django.db.models.BigAutoField"

AUTH_PASSWORD_VALIDATORS = [
    {"NAME": "django.contrib.auth.password_validation.UserAttributeSimilarityValidator"},
    {"NAME": "django.contrib.auth.password_validation.MinimumLengthValidator"},
    {"NAME": "django.contrib.auth.password_validation.CommonPasswordValidator"},
    {"NAME": "django.contrib.auth.password_validation.NumericPasswordValidator"},
]

LANGUAGE_CODE = "en-us"
TIME_ZONE = "UTC"
USE_I18N = True
USE_TZ = True

# ----------------------------------------------------------------------------- uploads
GCPS_MAX_UPLOAD_BYTES = env_int("GCPS_MAX_UPLOAD_BYTES", 512 * 1024 * 1024, minimum=1)
# Uploads above this go to a temporary file instead of memory.
FILE_UPLOAD_MAX_MEMORY_SIZE = 8 * 1024 * 1024
DATA_UPLOAD_MAX_MEMORY_SIZE = 8 * 1024 * 1024
# Largest image a stack may hold (width * height), guards against headers claiming huge sizes.
GCPS_MAX_STACK_PIXELS = env_int("GCPS_MAX_STACK_PIXELS", 64 * 1024 * 1024, minimum=1)
# Largest ``extra`` (the rig file's further keys) a rig may hold, bytes of JSON.
GCPS_MAX_RIG_EXTRA_BYTES = env_int("GCPS_MAX_RIG_EXTRA_BYTES", 16 * 1024, minimum=2)
# Largest rig or calibration file (JSON, OpenCV FileStorage) a page uploads, bytes.
GCPS_MAX_RIG_FILE_BYTES = env_int("GCPS_MAX_RIG_FILE_BYTES", 1024 * 1024, minimum=1024)
# Largest rig image side (width_px, height_px), pixels; and the memory a simulation may take, bytes.
GCPS_MAX_IMAGE_SIDE_PX = env_int("GCPS_MAX_IMAGE_SIDE_PX", 4096, minimum=1)
GCPS_MAX_SIMULATION_BYTES = env_int("GCPS_MAX_SIMULATION_BYTES", 4 * 1024**3, minimum=1)

# ----------------------------------------------------------------------------- derived result files
# Meshes (PLY, STL, OBJ) and TIFF height maps are built from the stored height map by a job when
# first asked for and kept in the storage's derived/ folder, at most this many bytes (oldest
# removed first).
GCPS_MESH_CACHE_BYTES = env_int("GCPS_MESH_CACHE_BYTES", 2 * 1024**3, minimum=0)
# Each worker process keeps decoded reference planes for the next jobs, at most this many bytes
# (about 34 MB per 1280x1024 reference), least recently used evicted first.
GCPS_REFERENCE_CACHE_BYTES = env_int("GCPS_REFERENCE_CACHE_BYTES", 256 * 1024**2, minimum=0)

# ----------------------------------------------------------------------------- REST API
REST_FRAMEWORK = {
    "DEFAULT_AUTHENTICATION_CLASSES": [
        "metrology.throttling.ThrottledTokenAuthentication",
        "rest_framework.authentication.SessionAuthentication",
    ],
    "DEFAULT_PERMISSION_CLASSES": ["metrology.throttling.IsAuthenticatedAnonThrottled"],
    "DEFAULT_THROTTLE_CLASSES": ["metrology.throttling.UserRateThrottle", "metrology.throttling.AnonRateThrottle"],
    # Client addresses for the rate limits: REMOTE_ADDR, or behind GCPS_NUM_PROXIES reverse proxies the
    # address they add to X-Forwarded-For (never the header as the client sent it: it could be forged).
    "NUM_PROXIES": env_int("GCPS_NUM_PROXIES", 1 if env_bool("GCPS_BEHIND_PROXY", False) else 0, minimum=0),
    "DEFAULT_SCHEMA_CLASS": "drf_spectacular.openapi.AutoSchema",
    "EXCEPTION_HANDLER": "metrology.api_errors.exception_handler",
    "DEFAULT_PAGINATION_CLASS": None,
    "DEFAULT_PARSER_CLASSES": [
        "metrology.api_input.BoundedJSONParser",
        "rest_framework.parsers.FormParser",
        "rest_framework.parsers.MultiPartParser",
    ],
    "UNAUTHENTICATED_USER": None,
}

# Rate limits (metrology/throttling.py): API requests per user and per anonymous client, failed
# log-ins and unknown API tokens per client address; past a rate the answer is 429 + Retry-After.
GCPS_THROTTLE_RATES = {
    "user": env_rate("GCPS_THROTTLE_USER", "1200/minute"),
    "anon": env_rate("GCPS_THROTTLE_ANON", "60/minute"),
    "login": env_rate("GCPS_THROTTLE_LOGIN", "10/minute"),
    "bad_token": env_rate("GCPS_THROTTLE_BAD_TOKEN", "20/minute"),
}

SPECTACULAR_SETTINGS = {
    "TITLE": "GCPS Lab API",
    "DESCRIPTION": (
        "Experiment database of a gray-code + phase-shift fringe-projection profilometer: rigs, "
        "capture stacks, measurements, calibrations and characterizations. Authenticate with "
        "`Authorization: Token <key>` (`python manage.py createuser NAME` prints a key)."
    ),
    "VERSION": "1",
    "SERVE_INCLUDE_SCHEMA": False,
    "SWAGGER_UI_DIST": "SIDECAR",
    "SWAGGER_UI_FAVICON_HREF": "SIDECAR",
    "REDOC_DIST": "SIDECAR",
    "COMPONENT_SPLIT_REQUEST": True,
    "POSTPROCESSING_HOOKS": [
        "drf_spectacular.hooks.postprocess_schema_enums",
        "metrology.api_schema.add_errors_and_examples",
    ],
    "ENUM_NAME_OVERRIDES": {
        "JobStatusEnum": "metrology.jobs.models.Job.Status",
        "CaptureRoleEnum": "metrology.captures.models.Capture.Role",
    },
}

# ----------------------------------------------------------------------------- Celery
REDIS_URL = env_url("REDIS_URL", ("redis", "rediss"))
CELERY_BROKER_URL = env_url("CELERY_BROKER_URL", ("redis", "rediss", "amqp", "memory")) or REDIS_URL
# The cache holds the rate-limit counters: Redis when REDIS_URL is set (shared by every web
# process), the process's memory otherwise (the embedded default is one process).
if REDIS_URL:
    CACHES = {
        "default": {
            "BACKEND": "django.core.cache.backends.redis.RedisCache",
            "LOCATION": REDIS_URL,
            "KEY_PREFIX": env_str("GCPS_CACHE_KEY_PREFIX", "gcps"),
        }
    }
else:
    CACHES = {"default": {"BACKEND": "django.core.cache.backends.locmem.LocMemCache", "LOCATION": "gcps"}}
# Without a broker, tasks run in-process when enqueued (the embedded default).
CELERY_TASK_ALWAYS_EAGER = not CELERY_BROKER_URL
if CELERY_BROKER_URL.startswith(("redis://", "rediss://")):
    # kombu's Redis transport, made to survive a Redis restart while messages are unacknowledged
    CELERY_BROKER_TRANSPORT = "workers.broker:Transport"
if CELERY_TASK_ALWAYS_EAGER:
    CELERY_BROKER_URL = "memory://localhost/"
CELERY_TASK_EAGER_PROPAGATES = False
CELERY_TASK_IGNORE_RESULT = True
CELERY_TASK_DEFAULT_QUEUE = env_str("GCPS_CELERY_QUEUE", "gcps")
# On Redis, priority 0 is consumed first: new jobs are sent at 6, recovered ones (a dead worker's job
# taken over, a lost message sent again) at 0, ahead of any backlog (metrology/jobs/services.py).
CELERY_TASK_DEFAULT_PRIORITY = 6
CELERY_TASK_ACKS_LATE = True
CELERY_TASK_REJECT_ON_WORKER_LOST = True
CELERY_WORKER_PREFETCH_MULTIPLIER = 1
CELERY_BROKER_CONNECTION_RETRY_ON_STARTUP = True
# A job running when the broker connection drops keeps running (its row, not its message, says
# whether it is done); its message, left unacknowledged, is dropped as done when redelivered.
CELERY_WORKER_CANCEL_LONG_RUNNING_TASKS_ON_CONNECTION_LOSS = False
# A message whose worker died unacknowledged is redelivered after this many seconds (Redis).
CELERY_BROKER_TRANSPORT_OPTIONS = {
    "visibility_timeout": env_int("GCPS_BROKER_VISIBILITY_TIMEOUT", 3600, minimum=1),
    # How often a worker looks for such messages (seconds; kombu scans every interval x throttle).
    "unacked_restore_interval": env_int("GCPS_BROKER_RESTORE_INTERVAL", 10, minimum=1),
    "unacked_restore_throttle": 1,
}
CELERY_TASK_SOFT_TIME_LIMIT = env_int("GCPS_TASK_SOFT_TIME_LIMIT", 1800, minimum=1)
CELERY_TASK_TIME_LIMIT = env_int("GCPS_TASK_TIME_LIMIT", 1900, minimum=1)
CELERY_BEAT_SCHEDULER = env_str("CELERY_BEAT_SCHEDULER", "django_celery_beat.schedulers:DatabaseScheduler")
CELERY_TIMEZONE = TIME_ZONE

# Jobs: a running job writes a heartbeat every GCPS_JOB_HEARTBEAT_SECONDS; one whose heartbeat is
# older than GCPS_JOB_STALE_SECONDS is taken over by a redelivered message or by the sweep, which
# every worker runs every GCPS_JOB_SWEEP_SECONDS (beat too, when it runs): a dead worker's job is
# taken over within about STALE + 1.2 x SWEEP seconds (15 + 6 = 21 s by default). The sweep also
# sends again the jobs queued for GCPS_JOB_RESEND_SECONDS without being claimed (a lost message).
GCPS_JOB_HEARTBEAT_SECONDS = env_int("GCPS_JOB_HEARTBEAT_SECONDS", 3, minimum=1)
GCPS_JOB_STALE_SECONDS = env_int("GCPS_JOB_STALE_SECONDS", 15, minimum=2)
GCPS_JOB_MAX_ATTEMPTS = env_int("GCPS_JOB_MAX_ATTEMPTS", 3, minimum=1)
GCPS_JOB_SWEEP_SECONDS = env_int("GCPS_JOB_SWEEP_SECONDS", 5, minimum=1)
GCPS_JOB_RESEND_SECONDS = env_int("GCPS_JOB_RESEND_SECONDS", 120, minimum=1)
# The embedded default (no broker) runs jobs in the web process: "background" (default) in one
# thread of its own, after the request that created them has committed and answered (the page
# shows their progress); "inline" in the request itself, which then waits (the tests' choice).
GCPS_EMBEDDED_JOBS = env_str("GCPS_EMBEDDED_JOBS", "background")
if GCPS_EMBEDDED_JOBS not in ("background", "inline"):
    raise ImproperlyConfigured(f"GCPS_EMBEDDED_JOBS must be background or inline, got {GCPS_EMBEDDED_JOBS!r}")
# Fault injection for tests: pause between the phases of a job (0 in production).
GCPS_JOB_PHASE_PAUSE_SECONDS = float(env_int("GCPS_JOB_PHASE_PAUSE_MS", 0, minimum=0)) / 1000.0

# Capture agents (issue 14): an agent not heard from for this long is disconnected and its
# running acquisition failed; agents beat every third of it.
GCPS_AGENT_TIMEOUT_SECONDS = env_float("GCPS_AGENT_TIMEOUT_SECONDS", 15.0, minimum=0.5)
# An acquisition no agent took within this many seconds fails with the reason (on the next read or sweep).
GCPS_ACQUISITION_TIMEOUT_SECONDS = env_float("GCPS_ACQUISITION_TIMEOUT_SECONDS", 600.0, minimum=1.0)

# Characterization reports: a figure "drifted" when it moved by more than its tolerance since the
# previous report of the same rig. Errors in mm, percentages of full scale, in-out slopes (unitless).
GCPS_REPORT_DRIFT_TOLERANCE = {
    "mm": env_float("GCPS_REPORT_DRIFT_TOLERANCE_MM", 0.010, minimum=0.0),
    "pct_fs": env_float("GCPS_REPORT_DRIFT_TOLERANCE_PCT_FS", 0.020, minimum=0.0),
    "slope": env_float("GCPS_REPORT_DRIFT_TOLERANCE_SLOPE", 0.001, minimum=0.0),
}

# ----------------------------------------------------------------------------- security
SECURE_PROXY_SSL_HEADER = ("HTTP_X_FORWARDED_PROTO", "https") if env_bool("GCPS_BEHIND_PROXY", False) else None
SECURE_SSL_REDIRECT = env_bool("SECURE_SSL_REDIRECT", not DEBUG)
SESSION_COOKIE_SECURE = env_bool("SESSION_COOKIE_SECURE", SECURE_SSL_REDIRECT)
CSRF_COOKIE_SECURE = env_bool("CSRF_COOKIE_SECURE", SECURE_SSL_REDIRECT)
SECURE_HSTS_SECONDS = env_int("SECURE_HSTS_SECONDS", 31536000 if SECURE_SSL_REDIRECT else 0, minimum=0)
SECURE_HSTS_INCLUDE_SUBDOMAINS = env_bool("SECURE_HSTS_INCLUDE_SUBDOMAINS", SECURE_HSTS_SECONDS > 0)
SECURE_HSTS_PRELOAD = env_bool("SECURE_HSTS_PRELOAD", SECURE_HSTS_SECONDS > 0)
SECURE_CONTENT_TYPE_NOSNIFF = True
X_FRAME_OPTIONS = "DENY"
# Content-Security-Policy of every response (metrology/security_headers.py says why each part);
# GCPS_CONTENT_SECURITY_POLICY="" sends none.
GCPS_CONTENT_SECURITY_POLICY = env_str(
    "GCPS_CONTENT_SECURITY_POLICY",
    "default-src 'self'; script-src 'self' 'unsafe-inline'; style-src 'self' 'unsafe-inline'; "
    "img-src 'self' data: blob:; font-src 'self' data:; connect-src 'self'; worker-src 'self' blob:; "
    "object-src 'none'; base-uri 'self'; form-action 'self'; frame-ancestors 'self'",
)

LOGIN_URL = "/login/"
LOGIN_REDIRECT_URL = "/"
LOGOUT_REDIRECT_URL = "/login/"

LOGGING = {
    "version": 1,
    "disable_existing_loggers": False,
    "handlers": {"console": {"class": "logging.StreamHandler"}},
    "root": {"handlers": ["console"], "level": env_str("LOG_LEVEL", "INFO").upper()},
}
