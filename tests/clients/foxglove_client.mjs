// A Foxglove WebSocket client made of Foxglove's own npm package (@foxglove/ws-protocol) and `ws`:
// connects to argv[2] asking for the subprotocol argv[4] (default: the package's own,
// foxglove.websocket.v1), subscribes to the comma-separated topics argv[3] as they are advertised,
// and prints one JSON line per event: protocol, serverInfo, advertise, subscribed, message.
import wsProtocol from "@foxglove/ws-protocol";  // a CommonJS package: its exports come as the default
import { WebSocket } from "ws";

const { FoxgloveClient } = wsProtocol;

const [url, topicList, subprotocol] = process.argv.slice(2);
const wanted = new Set(topicList.split(","));
const ws = new WebSocket(url, [subprotocol || FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const subscriptions = new Map();
const decoder = new TextDecoder();
const say = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");

client.on("open", () => say({ op: "protocol", protocol: ws.protocol }));
client.on("serverInfo", (info) => say({ op: "serverInfo", name: info.name }));
client.on("advertise", (channels) => {
  say({ op: "advertise", channels });
  for (const ch of channels) {
    if (wanted.has(ch.topic) && ![...subscriptions.values()].includes(ch.topic)) {
      subscriptions.set(client.subscribe(ch.id), ch.topic);
      say({ op: "subscribed", topic: ch.topic });
    }
  }
});
client.on("message", ({ subscriptionId, data }) => {
  say({ op: "message", topic: subscriptions.get(subscriptionId), data: JSON.parse(decoder.decode(data)) });
});
client.on("error", (e) => {
  process.stderr.write(`foxglove_client: ${e}\n`);
  process.exit(3);
});
client.on("close", () => process.exit(0));
process.stdin.on("end", () => { client.close(); process.exit(0); });  // the test closes our stdin to stop us
process.stdin.resume();
