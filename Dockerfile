# Installs srmpc from requirements.lock (exact versions, hashes checked; torch's CPU build) and runs the default
# test suite.
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
COPY pyproject.toml README.md LICENSE requirements.lock ./
COPY srmpc ./srmpc
RUN python -m pip install --require-hashes --no-deps -r requirements.lock \
    && python -m pip install --no-deps --no-build-isolation -e .
COPY . .

CMD ["python", "-m", "pytest"]
