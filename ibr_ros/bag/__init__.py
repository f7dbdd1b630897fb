# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Bag I/O: read ROS 2 / ROS 1 bags and bare MCAP files, write ROS 2 MCAP bags, detect topics, and the
playback policy of the bag_player (what to replay, with which QoS)."""

from ibr_ros.bag.detect import TopicSelection, detect_topics
from ibr_ros.bag.info import BagInfo, ImageDetails, TopicSummary, bag_info, format_bag_info
from ibr_ros.bag.playback import (
    PlaybackPlan,
    PlaybackPolicy,
    PlayedTopic,
    PlayQos,
    parse_remaps,
    parse_topic_qos,
    play_qos,
    play_window,
    undecodable,
    unplayable,
)
from ibr_ros.bag.qos import OfferedQos
from ibr_ros.bag.reader import (
    BagMessage,
    BagReader,
    Storage,
    TopicInfo,
    find_bags,
    open_bag,
    same_definition,
)
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
    'PlayQos',
    'PlaybackPlan',
    'PlaybackPolicy',
    'PlayedTopic',
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
    'parse_remaps',
    'parse_topic_qos',
    'play_qos',
    'play_window',
    'same_definition',
    'serialize',
    'undecodable',
    'unplayable',
]
