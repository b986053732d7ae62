"""Parse a /metrics scrape with Prometheus's own Python client (an independent parser, its
strict OpenMetrics one: a malformed exposition raises): stdin in, JSON out:
{family: {"type": ..., "samples": [[sample name, labels, value], ...]}}."""
import json
import sys

from prometheus_client.openmetrics.parser import text_string_to_metric_families

families = {}
for family in text_string_to_metric_families(sys.stdin.read()):
    families[family.name] = {"type": family.type, "samples": [[s.name, s.labels, s.value] for s in family.samples]}
print(json.dumps(families))
