# The README's commands. Each sets up what it needs (scripts/setup-env) on a fresh machine.
.PHONY: demo test lint setup clean

# A live simulated run (sim + controller + recorder) ending in a bag and a report.
demo:
	scripts/in-env python -m ladrc_tools.bringup.demo


# Lint (ruff: flake8 + pep257 rule sets, the ROS Python conventions), then every test, then the
# non-ROS suite on Ubuntu 24.04's library versions (Python 3.12, numpy 1.26), then each
# package's own tests the stock way (colcon test; tests/ is the full suite).
test:
	scripts/in-env ruff check .
	scripts/in-env python -m pytest
	scripts/noble-test
	scripts/in-env sh -c 'cd ros2_ws && python -m colcon test --packages-select ladrc_follow ladrc_sim ladrc_tools --return-code-on-test-failure --event-handlers console_cohesion- summary- && python -m colcon test-result --all'

lint:
	scripts/in-env ruff check .

setup:
	scripts/setup-env

clean:
	rm -rf ros2_ws/build ros2_ws/install ros2_ws/log
