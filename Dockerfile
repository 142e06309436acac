# IK service image: python -m service (uvicorn + create_app) as a non-root user.
# Configure with IK_* variables (docs/operations.md, "Configuration"). One process per container:
# the session store is in memory, so scale with replicas, not workers.
FROM python:3.11.7-slim-bookworm

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    OPENBLAS_NUM_THREADS=1 \
    NUMBA_CACHE_DIR=/app/numba-cache \
    IK_HOST=0.0.0.0 \
    IK_PORT=8000

WORKDIR /app

# The versions the test suite passed with (runtime dependencies and their dependencies).
RUN printf '%s\n' \
        annotated-doc==0.0.7 annotated-types==0.7.0 anyio==4.16.0 click==8.4.0 \
        defusedxml==0.7.1 fastapi==0.165.0 h11==0.16.0 httptools==0.9.0 idna==3.13 \
        llvmlite==0.50.0 msgpack==1.2.4 numba==0.68.1 numpy==2.4.6 orjson==3.13.0 \
        prometheus-client==0.26.0 pydantic==2.13.4 pydantic-core==2.46.4 \
        pydantic-settings==2.14.1 python-dotenv==1.2.2 pyyaml==6.0.3 sniffio==1.3.1 \
        starlette==1.10.0 typing-extensions==4.16.0 typing-inspection==0.4.2 \
        uvicorn==0.54.0 uvloop==0.23.0 watchfiles==1.3.0 websockets==17.4 \
        > /app/constraints.txt \
    && useradd --create-home --uid 10001 ik

COPY pyproject.toml README.md ./
COPY solver/ solver/
COPY schemas/ schemas/
COPY service/ service/

# Install; drop the sources so that everything imports from site-packages; compile
# the solver once so its numba cache ships in the image, owned by the runtime user
# (a container is ready in about a second instead of after a 30-60 s compile).
RUN pip install --constraint /app/constraints.txt . \
    && rm -rf /app/solver /app/schemas /app/service \
    && python -c "import solver; print(f'solver warm in {solver.warmup():.1f} s')" \
    && chown -R 10001:10001 /app/numba-cache

USER 10001
EXPOSE 8000
HEALTHCHECK --interval=10s --timeout=3s --start-period=120s --retries=3 \
    CMD ["python", "-c", "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:' + os.environ.get('IK_PORT', '8000') + '/healthz', timeout=2)"]
CMD ["python", "-m", "service"]
