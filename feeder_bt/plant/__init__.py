"""Plant integration: the cell's outer adapters beside the operator UI (``ui/``).

- ``part_server``: robots of any brand pull parts from the cell over a line-based TCP
  protocol (``feeder run --part-server``; the protocol is ``feeder_bt.core.part_protocol``,
  the server's side of the exchange is ``behaviours/desk.py`` and ``trees/desk.py``);
- ``client``: the reference robot client; ``sim_robot``: a robot program on the simulated
  robot, written against it;
- ``opcua``: the cell as an OPC UA server (``feeder run --opcua``), commanded under the
  dashboard's rules (``ua_security``: its users and the session hooks);
- ``robots``: which robots the part server trusts (the robots file, ``HELLO``);
  ``robot_port``: the simulated robot's motions for an outside program
  (``--sim-robot-port``), ``outside_robot`` such a program;
- ``adapters``: what one run opens, pumps after each tick and closes.

Every listener admits connections through ``ui.conns.ConnGate``.

Each is a thin translation onto the cell's own operations. This module imports nothing
heavy, so the command line can parse its options without loading asyncua.
"""
