"""A policy as one function: `serve(policy)` answers each observation on standard input with
`policy(observation, hello)` on standard output, episode after episode, until flowgate
closes the line. Run it as `flowgate plan --policy "python3 my_policy.py" SCENARIO`."""

from __future__ import annotations

import sys
from typing import Callable, Optional, TextIO

from .protocol import Command, Ending, Hello, Observation, read_message

Policy = Callable[[Observation, Hello], Command]


def serve(policy: Policy, stdin: Optional[TextIO] = None, stdout: Optional[TextIO] = None,
          on_end: Optional[Callable[[Ending], None]] = None) -> None:
    stdin = stdin or sys.stdin
    stdout = stdout or sys.stdout
    hello = None
    for line in stdin:
        message = read_message(line)
        if isinstance(message, Hello):
            hello = message
        elif isinstance(message, Observation):
            stdout.write(policy(message, hello).to_json() + "\n")
            stdout.flush()
        elif on_end is not None:
            on_end(message)
