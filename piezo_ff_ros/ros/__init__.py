"""Everything that starts or drives ROS 2 processes from a command: the safe environment (:mod:`.env`), the graph
launcher (:mod:`.launcher`), the client that configures and plays through the graph (:mod:`.graph_session`), the
ROS-graph rig of the commissioning sequence (:mod:`.graph_rig`) and ``piezo-ff commission`` over it
(:mod:`.commission`).  The nodes themselves live in :mod:`piezo_ff_ros.nodes`; the core never imports this.
"""
