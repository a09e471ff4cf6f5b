# One image for every fleet service, the zenoh router included (`fleet router`); the compose file
# picks the command. Configuration is not baked in: compose mounts deploy/ (router.json5, the radios
# and mocap files) read-only at /app/deploy, and the role credentials as secrets.
FROM python:3.11-slim
# The zenoh of the router and of every service: the version the tests run with
# (tests/test_compose.py checks that this pin is the installed eclipse-zenoh).
ARG ZENOH_VERSION=1.10.2
WORKDIR /app
# libusb for the Crazyradio (cflib's RadioDriver, through pyusb)
RUN apt-get update && apt-get install -y --no-install-recommends libusb-1.0-0 && rm -rf /var/lib/apt/lists/*
COPY pyproject.toml README.md ./
COPY common common
COPY services services
COPY maps maps
RUN pip install --no-cache-dir "eclipse-zenoh==${ZENOH_VERSION}" -e .
ENV PYTHONUNBUFFERED=1
CMD ["fleet", "--help"]
