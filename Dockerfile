# IK service image: python -m service (uvicorn + create_app) as a non-root user.
# Configure with IK_* variables (docs/operations.md, "Configuration"). One process per container:
# scale with replicas (sessions in Redis with IK_REDIS_URL, docker-compose.yml).
FROM python:3.11.7-slim-bookworm

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    OPENBLAS_NUM_THREADS=1 \
    NUMBA_CACHE_DIR=/app/numba-cache \
    NUMBA_CPU_NAME=generic \
    IK_HOST=0.0.0.0 \
    IK_PORT=8000

WORKDIR /app

RUN useradd --create-home --uid 10001 ik

# The versions the test suite passed with (constraints.txt: runtime, test and bench
# extras verified together; README and .ci/run install with it too).
COPY constraints.txt pyproject.toml README.md ./
COPY solver/ solver/
COPY schemas/ schemas/
COPY service/ service/

# Install; drop the sources so that everything imports from site-packages; compile
# the solver once so its numba cache ships in the image, owned by the runtime user
# (a container is ready in about a second instead of after a 3-4 minute compile).
# NUMBA_CPU_NAME=generic: numba keys its cache by CPU, and generic x86-64 code loads on
# any node (no slower here: docs/operations.md, "Container").
RUN pip install --constraint constraints.txt '.[redis]' \
    && rm -rf /app/solver /app/schemas /app/service \
    && python -c "import solver; print(f'solver warm in {solver.warmup():.1f} s')" \
    && chown -R 10001:10001 /app/numba-cache

USER 10001
EXPOSE 8000
HEALTHCHECK --interval=10s --timeout=3s --start-period=120s --retries=3 \
    CMD ["python", "-c", "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:' + os.environ.get('IK_PORT', '8000') + '/healthz', timeout=2)"]
CMD ["python", "-m", "service"]
