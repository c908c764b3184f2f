"""World models, one small module each: the jig's stage, the load cell, the gripper's fingers and
skin, objects and parts, a scripted hand, friction, a table, a stick, torsion, stirring and the
stick press of the force-map session. Each registers its kind with :func:`tactile_rig.sim.register_model`."""
