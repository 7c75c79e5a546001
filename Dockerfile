# GCPS Lab: one image for the web server, the Celery workers and beat.
FROM python:3.11-slim-bookworm

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    DJANGO_SETTINGS_MODULE=metrology.settings \
    MEDIA_ROOT=/data/media \
    STATIC_ROOT=/app/var/static

# libgomp1: OpenMP runtime of open3d; libgl1/libglib2.0-0/libusb-1.0-0: needed by open3d's import.
RUN apt-get update \
    && apt-get install -y --no-install-recommends libgomp1 libgl1 libglib2.0-0 libusb-1.0-0 \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /app
COPY pyproject.toml README.md ./
COPY metrology ./metrology
COPY workers ./workers
COPY templates ./templates
COPY manage.py ./
# the sources under /app are what the processes import (the working directory comes first on their
# path): compiled here, since PYTHONDONTWRITEBYTECODE keeps each process from writing the bytecode and
# every web server and worker would compile them again as it starts (0.3-0.7 s of CPU for a worker
# on the test machine)
RUN pip install . \
    && python -m compileall -q metrology workers manage.py \
    && useradd --system --uid 1000 --home /app gcps \
    && mkdir -p /data/media /app/var/static /app/var/cache \
    && SECRET_KEY=build-only-not-secret-build-only-not-secret-build-only DEBUG=1 \
       python manage.py collectstatic --noinput \
    && chown -R gcps /data /app/var

USER gcps
VOLUME ["/data/media"]
EXPOSE 8000
# ASGI (uvicorn workers): long-polls wait without holding a worker. docker-compose.yml runs it behind nginx.
CMD ["gunicorn", "metrology.asgi:application", "-k", "uvicorn_worker.UvicornWorker", "--bind", "0.0.0.0:8000", "--workers", "3", "--timeout", "120"]
