"""The policy end of `FlowgateEnv`: flowgate runs this as its policy (`--policy`), and it
carries the protocol's lines between flowgate's pipes and the environment's Unix socket."""

import socket
import sys
import threading


def main() -> None:
    conn = socket.socket(socket.AF_UNIX)
    conn.connect(sys.argv[1])
    to_env = conn.makefile("wb")
    from_env = conn.makefile("rb")

    def forward() -> None:
        for line in sys.stdin.buffer:
            to_env.write(line)
            to_env.flush()
        conn.shutdown(socket.SHUT_WR)

    threading.Thread(target=forward, daemon=True).start()
    for line in from_env:
        sys.stdout.buffer.write(line)
        sys.stdout.buffer.flush()


if __name__ == "__main__":
    main()
