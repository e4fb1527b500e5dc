#!/usr/bin/env python3
"""rostest node of test/ros/remapped_depth.test: the perception, told the renamed depth topic,
publishes objects, and nothing is published under the old name. Waits on the wall clock: the
looping bag's clock jumps back, which rospy's own sleeps take for an error."""
import time
import unittest

import rospy
import rostest
from sensor_msgs.msg import Image
from simstack.msg import ObjectArray


class RemappedDepth(unittest.TestCase):
    def test_objects_come_from_the_renamed_topic(self):
        rospy.init_node("test_remapped_depth")
        objects, old_name = [], []
        rospy.Subscriber("/camera/perception/objects", ObjectArray, objects.append)
        rospy.Subscriber("/camera/depth/image_rect", Image, old_name.append)
        deadline = time.time() + 120
        while not objects and time.time() < deadline:
            time.sleep(0.05)
        self.assertTrue(objects, "no objects within 120 s")
        self.assertGreater(len(objects[0].objects), 0)
        time.sleep(2.0)  # and a while more under the old name
        self.assertEqual(len(old_name), 0, "a depth image on the old name")


if __name__ == "__main__":
    rostest.rosrun("simstack", "remapped_depth", RemappedDepth)
