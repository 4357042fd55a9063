"""depthmocap: real-time full-body motion capture from one depth camera."""
