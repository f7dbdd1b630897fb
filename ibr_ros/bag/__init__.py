"""Bag I/O: read ROS 2 / ROS 1 bags and bare MCAP files, write ROS 2 MCAP bags, detect topics."""

from ibr_ros.bag.detect import TopicSelection, detect_topics
from ibr_ros.bag.info import BagInfo, ImageDetails, TopicSummary, bag_info, format_bag_info
from ibr_ros.bag.qos import OfferedQos
from ibr_ros.bag.reader import BagMessage, BagReader, Storage, TopicInfo, find_bags, open_bag
from ibr_ros.bag.typestore import STORE, TYPESTORE, msgtype_of, serialize
from ibr_ros.bag.writer import BagWriter, Compression

__all__ = [
    'STORE',
    'TYPESTORE',
    'BagInfo',
    'BagMessage',
    'BagReader',
    'BagWriter',
    'Compression',
    'ImageDetails',
    'OfferedQos',
    'Storage',
    'TopicInfo',
    'TopicSelection',
    'TopicSummary',
    'bag_info',
    'detect_topics',
    'find_bags',
    'format_bag_info',
    'msgtype_of',
    'open_bag',
    'serialize',
]
