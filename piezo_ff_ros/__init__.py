"""piezo_ff_ros: sensorless feedforward compensation of multi-axis piezoelectric positioners (ROS 2).

The method is Habineza, Zouari, Le Gorrec, Rakotondrabe, IEEE TASE 15(4) 2018: multivariable Bouc-Wen hysteresis,
multivariable creep K + Cr(s) and an H∞ feedforward compensator for the badly damped MIMO dynamics, in cascade.
``piezo_ff_ros.core`` holds everything that is not ROS (and never imports rclpy); ``piezo_ff_ros.nodes`` the nodes.
"""
__version__ = "0.1.0"
