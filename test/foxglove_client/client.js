// A Foxglove WebSocket client made of Foxglove's own packages, as the Foxglove app decodes a
// ROS 2 live connection: @foxglove/ws-protocol speaks the protocol, @foxglove/rosmsg parses each
// channel's ros2msg schema, @foxglove/rosmsg2-serialization decodes the CDR payloads.
//
//   node client.js ws://127.0.0.1:PORT SECONDS [TOPIC,TOPIC,... [WAIT_SECONDS]]
//
// Subscribes to every channel the server advertises, decodes every message for SECONDS after
// the first force estimate arrives and, if TOPICs are named, until a message of each has come
// too (for at most WAIT_SECONDS, 20 unless told, after the first estimate: a latched message
// reaches the server only once ROS discovery has matched its publisher, which a loaded machine
// can take seconds to do), then prints one JSON object: per topic, the channel's
// encodings and schema name, the number of messages decoded, each stamped message's header stamp
// ([sec, nanosec]) and the values of the small topics (reference, band, diagnostics' names).
// A message that does not decode ends the client with exit code 1.
'use strict';

const { FoxgloveClient } = require('@foxglove/ws-protocol');
const { parse } = require('@foxglove/rosmsg');
const { MessageReader } = require('@foxglove/rosmsg2-serialization');

const [url, secondsText, awaitedText = '', waitText = '20'] = process.argv.slice(2);
const seconds = Number(secondsText);
const awaited = awaitedText.split(',').filter((topic) => topic !== '');
const waitSeconds = Number(waitText);
let started = null; // when the first force estimate came [ms]
// foxglove-sdk servers name the protocol foxglove.sdk.v1: the same messages as
// foxglove.websocket.v1 under a new name. The client offers both, as the Foxglove app does, and
// the server picks.
const client = new FoxgloveClient({
  ws: new WebSocket(url, ['foxglove.sdk.v1', FoxgloveClient.SUPPORTED_SUBPROTOCOL]),
});
const subscriptions = new Map(); // subscription id -> { topic, decode }
const topics = {};
let finishing = null;

function decoderOf(channel) {
  if (channel.encoding === 'cdr' && channel.schemaEncoding === 'ros2msg') {
    const reader = new MessageReader(parse(channel.schema, { ros2: true }));
    return (bytes) => reader.readMessage(bytes);
  }
  if (channel.encoding === 'json') {
    const text = new TextDecoder();
    return (bytes) => JSON.parse(text.decode(bytes));
  }
  throw new Error(`${channel.topic}: no decoder for ${channel.encoding}/${channel.schemaEncoding}`);
}

// Finishes once every awaited topic has a message, or WAIT_SECONDS after the first estimate
// (the output then shows the awaited topic with no values).
function finishWhenHeard() {
  const missing = awaited.filter((topic) => !(topics[topic] && topics[topic].count > 0));
  if (missing.length === 0 || Date.now() - started >= waitSeconds * 1000) {
    finish();
  } else {
    finishing = setTimeout(finishWhenHeard, 100);
  }
}

function finish() {
  client.close();
  // Exit once the output is out: a pipe takes a large write asynchronously.
  process.stdout.write(JSON.stringify({ topics }) + '\n', () => process.exit(0));
}

client.on('advertise', (channels) => {
  for (const channel of channels) {
    topics[channel.topic] = {
      encoding: channel.encoding, schemaEncoding: channel.schemaEncoding,
      schemaName: channel.schemaName, count: 0, stamps: [], values: [],
    };
    const id = client.subscribe(channel.id);
    subscriptions.set(id, { topic: channel.topic, decode: decoderOf(channel) });
  }
});

client.on('message', ({ subscriptionId, data }) => {
  const { topic, decode } = subscriptions.get(subscriptionId);
  let message;
  try {
    message = decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  } catch (error) {
    process.stderr.write(`${topic}: cannot decode: ${error}\n`);
    process.exit(1);
  }
  const entry = topics[topic];
  entry.count += 1;
  if (message.header !== undefined) {
    entry.stamps.push([message.header.stamp.sec, message.header.stamp.nanosec]);
  }
  if (topic === '/force/reference') {
    entry.values.push(message.data);
  } else if (topic === '/session/settings') {
    // The YAML's top-level keys (the texts are long): what each settings message held.
    entry.values.push(message.data.split('\n').filter((l) => /^\S.*:/.test(l))
      .map((l) => l.split(':')[0]));
  } else if (topic === '/view/band' && entry.values.length === 0) {
    entry.values.push(message);
  } else if (topic === '/diagnostics') {
    for (const status of message.status) {
      if (!entry.values.includes(status.name)) entry.values.push(status.name);
    }
  }
  if (finishing === null && topic === '/force/estimate') {
    started = Date.now();
    finishing = setTimeout(finishWhenHeard, seconds * 1000);
  }
});

client.on('error', (error) => {
  process.stderr.write(`client error: ${error}\n`);
  process.exit(1);
});
client.on('close', () => {
  if (finishing !== null) return;
  process.stderr.write('the server closed the connection\n');
  process.exit(1);
});
