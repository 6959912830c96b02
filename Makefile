# The README's commands. Each sets up what it needs (scripts/setup-env) on a fresh machine.
.PHONY: demo demo-live test lint setup clean

# The showcase live on ROS (sim + controller + recorder) in lock step paced to real time,
# ending in a bag and its report; demo-live: the same free-running (the product's own loop).
demo:
	scripts/in-env python -m ladrc_bringup.demo

demo-live:
	scripts/in-env python -m ladrc_bringup.demo --free-running


# Lint (ruff: flake8 + pep257 rule sets, the ROS Python conventions), then every test in two
# lanes (scripts/run-tests): the ROS tests, and beside them the rest of the suite, the non-ROS
# suite on Ubuntu 24.04's library versions (Python 3.12, numpy 1.26) and each package's own
# tests the stock way (colcon test; tests/ is the full suite).
test:
	scripts/in-env ruff check .
	scripts/run-tests

lint:
	scripts/in-env ruff check .

setup:
	scripts/setup-env

clean:
	rm -rf ros2_ws/build ros2_ws/install ros2_ws/log
