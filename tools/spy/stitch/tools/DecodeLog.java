// Decodes every message of an LCM log with the LCM types on the class path (stitch's generated
// Java types, in the same jar), the way lcm-spy finds them: by each message's fingerprint. Prints
// one line per channel: channel, type, messages, decoded, undecodable, bytes (of messages) and
// bytes per second (from the channel's first message to its last). `stitch spy --log FILE`
// runs it; a channel whose type is unknown shows "??" as lcm-spy would.
package stitch.tools;

import java.io.EOFException;
import java.nio.ByteBuffer;
import java.util.Map;
import java.util.TreeMap;

import lcm.logging.Log;
import lcm.spy.LCMTypeDatabase;

public final class DecodeLog {
  private static final class Channel {
    String type = "??";
    long messages = 0;
    long decoded = 0;
    long failed = 0;
    long bytes = 0;
    long first = -1, last = -1;  // utime of its first and last message
  }

  public static void main(String[] args) throws Exception {
    if (args.length != 1) {
      System.err.println("usage: DecodeLog FILE.lcmlog");
      System.exit(2);
    }
    final LCMTypeDatabase types = new LCMTypeDatabase();
    final Map<String, Channel> channels = new TreeMap<>();
    final Log log = new Log(args[0], "r");
    try {
      while (true) {
        final Log.Event event;
        try {
          event = log.readNext();
        } catch (EOFException end) {
          break;
        }
        final Channel channel = channels.computeIfAbsent(event.channel, name -> new Channel());
        ++channel.messages;
        channel.bytes += event.data.length;
        if (channel.first < 0) channel.first = event.utime;
        channel.last = event.utime;
        if (event.data.length < 8) {
          ++channel.failed;
          continue;
        }
        final Class<?> type = types.getClassByFingerprint(ByteBuffer.wrap(event.data, 0, 8).getLong());
        if (type == null) {
          ++channel.failed;
          continue;
        }
        channel.type = type.getName();
        try {
          type.getConstructor(byte[].class).newInstance((Object) event.data);
          ++channel.decoded;
        } catch (ReflectiveOperationException damaged) {
          ++channel.failed;
        }
      }
    } finally {
      log.close();
    }
    if (channels.isEmpty() && new java.io.File(args[0]).length() > 0) {
      System.err.println(args[0] + ": not an LCM log (no event found)");
      System.exit(1);
    }
    System.out.println("channel\ttype\tmessages\tdecoded\tundecodable\tbytes\tbytes_per_s");
    for (Map.Entry<String, Channel> entry : channels.entrySet()) {
      final Channel c = entry.getValue();
      final long spanUs = c.last - c.first;
      final long rate = spanUs > 0 ? (long) Math.floor(c.bytes * 1e6 / spanUs) : 0;
      System.out.println(entry.getKey() + "\t" + c.type + "\t" + c.messages + "\t" + c.decoded + "\t" + c.failed
          + "\t" + c.bytes + "\t" + rate);
    }
  }
}
