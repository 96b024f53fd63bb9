"""ROS logs as a source: ROS 1 bags, ROS 2 bag folders and bare MCAP / db3 files read with `rosbags` (`bag`),
image messages as grey frames (`images`), ground truth from a pose topic (`ground_truth`), message fields of
both ROS versions behind one error boundary (`messages`), and a cut-short MCAP read as a stream
(`mcap_recovery`)."""
