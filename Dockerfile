# Installs srmpc with its test extras and runs the default test suite.
# Note: on x86_64 Linux, PyPI's torch==2.13.0 is a CUDA build (several GB).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PIP_NO_CACHE_DIR=1 \
    SDL_VIDEODRIVER=dummy

# Debian's security updates are wanted, so apt packages are not pinned.
# hadolint ignore=DL3008
RUN apt-get update \
    && apt-get install -y --no-install-recommends git make \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /srmpc
COPY pyproject.toml README.md ./
COPY srmpc ./srmpc
RUN python -m pip install -e '.[dev]'
COPY . .

CMD ["python", "-m", "pytest"]
