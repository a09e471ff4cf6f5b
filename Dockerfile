# One image for every fleet service (compose.yaml picks the command).
FROM python:3.11-slim
WORKDIR /app
RUN apt-get update && apt-get install -y --no-install-recommends libusb-1.0-0 && rm -rf /var/lib/apt/lists/*
COPY pyproject.toml README.md ./
COPY common common
COPY services services
COPY maps maps
COPY deploy deploy
RUN pip install --no-cache-dir -e .
ENV PYTHONUNBUFFERED=1
CMD ["fleet", "--help"]
