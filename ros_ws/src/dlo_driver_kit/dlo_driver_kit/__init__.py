"""dlo_driver_kit: the reference driver for a real robot and the checker of the driver contract.

``mock_driver_node`` (:mod:`dlo_driver_kit.mock_driver_node`): the driver template, a kinematic
stand-in for the sim; ``dlo-driver-check`` (:mod:`dlo_driver_kit.driver_check`): checks the driver
running on this ROS domain against the topic contract, rule by rule (docs/WRITE_YOUR_DRIVER.md).
"""
