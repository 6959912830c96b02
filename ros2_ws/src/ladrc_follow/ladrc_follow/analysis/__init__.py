"""Analysis of parameter sets, beside the control core (pure Python + numpy, no rclpy).

Not on the tick path: the linear loop of a set (:mod:`.loop`) and the stability gate built on
it (:mod:`.gate`). The node gates a set at start-up and on a change (in a worker process,
``node/gate_process.py``); the tools gate where they load a set to run it.
"""
