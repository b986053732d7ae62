"""Planners for flowgate: the JSON-lines protocol of `flowgate plan --policy CMD` as Python
types (`protocol`), a helper to write a policy as one function (`serve`), and a Gymnasium
environment in which Python drives the whole stack (`flowgate_policy.env.FlowgateEnv`, with
the `gym` extra). The protocol is docs/policies.md's."""

from .protocol import Command, Ending, Hello, Limits, Observation, Obstacle, Robot, read_message
from .serve import serve

__all__ = ["Command", "Ending", "Hello", "Limits", "Observation", "Obstacle", "Robot", "read_message", "serve"]
