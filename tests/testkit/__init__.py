"""What the tests share, imported by name: the embedded sample and the ``seesys`` command (``sample``), waiting on
a condition (``polling``), and the helpers of the advisory (``audio``), service (``service``), feature stream
(``stream``), renderer (``renders``), ROS bag (``bags``), Ray (``ray_cluster``), estimator (``deepsee``) and
motion-capture (``mocap``) tests. Their fixtures reach every test through ``tests/conftest.py``, never by an import
of a test module."""
